"""Training, rendering and export in the real Blender (bpy module), and the headless script.

A tiny synthetic capture is trained for a few steps through ``mogaface.train`` (a child
process); its avatar is then linked to the imported head, rendered from a capture camera and
compared with the core's own render of the same frame, exported as a PLY, and the batch
script builds and saves a whole scene that reopens with everything in it.
"""

import importlib
import json
import os
import pathlib
import subprocess
import sys
import time
import tomllib

import test_blender_addon as addon_test  # sets Blender's user folders to a temporary one first

# isort: split

import bpy  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from conftest import make_toy_model  # noqa: E402

from mogaface.core.avatar.avatar import (
    Avatar,  # noqa: E402
    render_frame,  # noqa: E402
)
from mogaface.core.data.capture import Capture  # noqa: E402
from mogaface.core.data.generator import CaptureSettings, make_capture  # noqa: E402
from mogaface.core.flame.model_file import write_model_file  # noqa: E402
from mogaface.core.for_blender.avatar import load_avatar  # noqa: E402
from mogaface.core.for_blender.axes import timestep_to_frame  # noqa: E402
from mogaface.core.for_blender.head_rig import AVATAR_PATH_PROPERTY, POSE_PROPERTIES  # noqa: E402
from mogaface.core.for_blender.render import render_image_name  # noqa: E402
from mogaface.core.for_blender.tracking import read_tracking  # noqa: E402
from mogaface.core.for_blender.worker import TrainWorker, train_command  # noqa: E402
from mogaface.core.run.folder import RunFolder  # noqa: E402

MODULE = addon_test.MODULE
ROOT = addon_test.ROOT
SCRIPT = ROOT / "scripts" / "mogaface_blend.py"
STEPS = 10


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("blender_avatar")
    capture = make_capture(root / "capture", CaptureSettings(views=3, timesteps=16, size=48, supersample=1),
                           progress=False)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon_test.build_and_install(root / "dist")
    train = importlib.import_module(MODULE + ".operators.train")
    run = root / "run"
    result = bpy.ops.mogaface.train(capture=str(capture), run=str(run), preset="quick", steps=STEPS)
    progress = train.last_progress()
    return {"root": root, "capture": capture, "run": run, "result": result, "progress": progress, "train": train}


def test_train_operator_reads_progress_and_completes_the_run(trained):
    assert trained["result"] == {"FINISHED"}
    progress = trained["progress"]
    assert progress.state == "done" and progress.step == progress.steps == STEPS
    assert progress.loss is not None and progress.psnr is not None and progress.fraction == 1.0
    run = trained["run"]
    assert (run / "avatar.pt").exists() and len(list((run / "flame_param").glob("*.npz"))) > 0
    assert json.loads((run / "run.json").read_text())["complete"] is True
    assert trained["train"].current_worker() is None
    assert bpy.context.scene.mogaface.run_folder == str(run)


def test_cancel_stops_with_a_checkpoint(trained):
    train, run = trained["train"], trained["root"] / "run_cancel"
    worker = TrainWorker(train_command(sys.executable, trained["capture"], run, preset="quick", steps=5000), run)
    train._job["worker"] = worker.start()
    try:
        while worker.poll().step < 5 and not worker.progress.finished:
            time.sleep(0.1)
        assert bpy.ops.mogaface.train_cancel() == {"FINISHED"}
        progress = worker.wait(interval=0.1, timeout=60)
    finally:
        train._job["worker"] = None
        worker.kill()
    assert progress.state == "cancelled", (progress.message, worker.events[-3:], worker.stderr_tail())
    assert (run / "checkpoints" / "latest").exists() and not (run / "avatar.pt").exists()
    assert any(e["event"] == "stopped" for e in worker.events)
    assert json.loads((run / "run.json").read_text())["complete"] is False
    assert not bpy.ops.mogaface.train_cancel.poll()  # nothing left running


def test_train_operator_starts_a_data_parallel_run_through_the_launcher(trained, tmp_path):
    prefs = bpy.context.preferences.addons[MODULE].preferences
    prefs.launcher = f"{sys.executable} -m torch.distributed.run --standalone --nproc_per_node 2"
    try:
        run = tmp_path / "run"
        assert bpy.ops.mogaface.train(capture=str(trained["capture"]), run=str(run), preset="quick",
                                      steps=3) == {"FINISHED"}
    finally:
        prefs.launcher = ""
    assert trained["train"].last_progress().state == "done"
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert [e["event"] for e in events].count("start") == 1 and events[-1]["event"] == "done"
    assert not any(e["event"] == "warning" for e in events)  # no rank left without an image
    settings = tomllib.loads((run / "config.toml").read_text())["train"]
    assert (settings["batch"], settings["steps"]) == (2, 2)  # an image per rank, 3 images' steps halved


def test_a_time_budget_from_the_panel_runs_the_schedule_through_its_minutes(trained, tmp_path):
    run = tmp_path / "run"
    assert bpy.ops.mogaface.train(capture=str(trained["capture"]), run=str(run), preset="quick",
                                  minutes=0.002) == {"FINISHED"}
    assert trained["train"].last_progress().state == "done"
    settings = tomllib.loads((run / "config.toml").read_text())["train"]
    assert (settings["max_minutes"], settings["schedule"]) == (0.002, "minutes")
    assert json.loads((run / "run.json").read_text())["time_limited"]


def test_camera_rounds_train_in_one_operator_call_and_show_their_stage(trained, tmp_path):
    run = tmp_path / "run"
    assert bpy.ops.mogaface.train(capture=str(trained["capture"]), run=str(run), preset="quick", steps=3,
                                  camera_rounds=2) == {"FINISHED"}
    progress = trained["train"].last_progress()
    assert progress.state == "done" and progress.stage is None  # the last round is the run itself
    assert (run / "camera_rounds" / "1" / "avatar.pt").exists() and (run / "cameras_refined.json").exists()
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert {e.get("stage") for e in events} == {"camera round 1/2", None}


def test_a_crashing_training_is_reported_with_its_message(trained, tmp_path):
    with pytest.raises(RuntimeError, match=r"exit code 2.*not-a-capture"):
        bpy.ops.mogaface.train(capture=str(tmp_path / "not-a-capture"), run=str(tmp_path / "run"), steps=2)
    assert trained["train"].last_progress().state == "failed"
    prefs = bpy.context.preferences.addons[MODULE].preferences
    prefs.python_path = sys.executable
    try:
        prefs.python_path = str(pathlib.Path("/bin/false"))
        with pytest.raises(RuntimeError, match="exit code 1"):
            bpy.ops.mogaface.train(capture=str(trained["capture"]), run=str(tmp_path / "run2"), steps=2)
        prefs.python_path = str(tmp_path / "no-such-python")
        with pytest.raises(RuntimeError, match="Cannot start"):
            bpy.ops.mogaface.train(capture=str(trained["capture"]), run=str(tmp_path / "run3"), steps=2)
    finally:
        prefs.python_path = sys.executable
    assert trained["train"].current_worker() is None


def test_worker_ignores_events_of_earlier_sessions_and_partial_lines(tmp_path):
    from mogaface.core.for_blender.worker import EventReader

    path = tmp_path / "events.jsonl"
    path.write_text('{"event": "iter", "step": 1}\n{"event": "it')
    reader = EventReader(path)
    assert [e["step"] for e in reader.read()] == [1]
    with open(path, "a") as handle:
        handle.write('er", "step": 2}\n')
    assert [e["step"] for e in reader.read()] == [2]
    assert reader.read() == []


@pytest.fixture(scope="module")
def scene(trained):
    run = trained["run"]
    assert bpy.ops.mogaface.import_capture(filepath=str(trained["capture"])) == {"FINISHED"}
    identity = sorted((run / "flame_param").glob("*.npz"))[0]
    assert bpy.ops.mogaface.import_head(filepath=str(run / "head.pkl"), shape_file=str(identity)) == {"FINISHED"}
    head = bpy.context.active_object
    assert bpy.ops.mogaface.import_tracking(directory=str(run / "flame_param")) == {"FINISHED"}
    assert bpy.ops.mogaface.load_avatar(filepath=str(run)) == {"FINISHED"}
    return {**trained, "head": head}


def use_camera(camera_id: str):
    obj = next(o for o in bpy.context.scene.objects if o.get("mogaface_camera_id") == camera_id)
    importlib.import_module(MODULE + ".operators.import_capture").apply_render_settings(bpy.context.scene, obj)
    return obj


def core_render(run: pathlib.Path, timestep: int, camera) -> np.ndarray:
    """The core's render (Blender's pixel order) of a run's avatar at a training timestep."""
    folder = RunFolder(run)
    rgb, alpha = render_frame(Avatar.load(run / "avatar.pt"), folder.flame_params(timestep), camera,
                                  folder.background)
    return blender_image(rgb)


def blender_image(rgb) -> np.ndarray:
    """What an opaque render over the training background must be in a Blender image: its sRGB
    colours decoded to scene-linear (IEC 61966-2-1), alpha 1, rows from the bottom."""
    linear = np.where(rgb > 0.04045, ((rgb + 0.055) / 1.055) ** 2.4, rgb / 12.92)
    return np.concatenate([linear, np.ones_like(rgb[..., :1])], axis=2)[::-1].astype(np.float32)


def image_array(image) -> np.ndarray:
    pixels = np.zeros(len(image.pixels), np.float32)
    image.pixels.foreach_get(pixels)
    return pixels.reshape(image.size[1], image.size[0], 4)


def test_render_frame_equals_the_core_render(scene):
    capture = Capture.open(scene["capture"])
    timestep = RunFolder(scene["run"]).trained_timesteps[1]
    frame = timestep_to_frame(timestep)
    for camera_id, camera in capture.cameras.items():
        obj = use_camera(camera_id)
        bpy.context.scene.frame_set(frame)
        assert bpy.ops.mogaface.render_frame() == {"FINISHED"}
        got = image_array(bpy.data.images[render_image_name(obj.name, frame)])
        expected = core_render(scene["run"], timestep, camera)
        assert got.shape == expected.shape
        # Blender keeps camera settings in float32: pixel positions move by ~1e-6 px, which changes
        # values at the sharpest Gaussian edges by up to ~4e-4 (measured); a wrong camera, frame or
        # expression changes them by more than 0.05.
        assert np.abs(got - expected).max() < 1e-3, camera_id
        assert expected[..., 1].std() > 0.02  # the head is in view


def test_a_mogaface_run_renders_with_its_modules(scene):
    """A run with MoGaFace modules: keyed with its corrected tracking, rendered as the core renders it."""
    from mogaface.core.correction.avatar import ModulatedAvatar

    run = scene["root"] / "run_mogaface"
    command = train_command(sys.executable, scene["capture"], run, preset="mogaface-demo", steps=5)
    assert TrainWorker(command, run).start().wait(interval=0.1, timeout=120).state == "done"
    head = scene["head"]
    assert bpy.ops.mogaface.import_tracking(directory=str(run / "flame_param_corrected"),
                                            target=head.name) == {"FINISHED"}
    assert bpy.ops.mogaface.load_avatar(filepath=str(run), target=head.name) == {"FINISHED"}
    try:
        avatar = RunFolder(run).load_avatar()
        assert isinstance(avatar, ModulatedAvatar) and isinstance(load_avatar(run / "avatar.pt"), ModulatedAvatar)
        timestep = RunFolder(run).trained_timesteps[0]
        frame = timestep_to_frame(timestep)
        camera_id, camera = next(iter(Capture.open(scene["capture"]).cameras.items()))
        obj = use_camera(camera_id)
        bpy.context.scene.frame_set(frame)
        assert bpy.ops.mogaface.render_frame(head=head.name) == {"FINISHED"}
        got = image_array(bpy.data.images[render_image_name(obj.name, frame)])
        folder = RunFolder(run)
        rgb, alpha = render_frame(avatar, folder.flame_params(timestep), camera, folder.background)
        expected = blender_image(rgb)
        assert np.abs(got - expected).max() < 1e-4
    finally:  # back to the plain run for the tests below
        assert bpy.ops.mogaface.import_tracking(directory=str(scene["run"] / "flame_param"),
                                                target=head.name) == {"FINISHED"}
        assert bpy.ops.mogaface.load_avatar(filepath=str(scene["run"]), target=head.name) == {"FINISHED"}


def test_blender_camera_converts_back_to_the_capture_camera(scene):
    for camera_id, camera in Capture.open(scene["capture"]).cameras.items():
        obj = use_camera(camera_id)
        avatar_head = importlib.import_module(MODULE + ".operators.avatar_head")
        back = avatar_head.camera_of(bpy.context.scene, obj, scene["head"])
        assert np.abs(back.K - camera.K).max() < 1e-3 and np.abs(back.w2c - camera.w2c).max() < 1e-5
        assert (back.width, back.height) == (camera.width, camera.height)


def test_what_is_keyframed_is_what_is_rendered(scene):
    """Editing a keyframed expression changes the render; the edit's value is what the core is given."""
    use_camera(next(iter(Capture.open(scene["capture"]).cameras)))
    head = scene["head"]
    frame = bpy.context.scene.frame_start
    avatar_head = importlib.import_module(MODULE + ".operators.avatar_head")
    rgb_before = avatar_head.render_head(bpy.context, head, bpy.context.scene.camera, frame).rgb
    fcurves = head.data.shape_keys.animation_data.action.layers[0].strips[0].channelbags[0].fcurves
    curve = next(c for c in fcurves if "key_blocks" in c.data_path)
    point = next(p for p in curve.keyframe_points if p.co[0] == frame)
    old = point.co[1]
    point.co[1] = old + 3.0
    try:
        rgb_after = avatar_head.render_head(bpy.context, head, bpy.context.scene.camera, frame).rgb
        params = avatar_head.head_params(head, load_avatar(head[AVATAR_PATH_PROPERTY]))
    finally:
        point.co[1] = old
    assert np.abs(rgb_after - rgb_before).max() > 1e-3
    block = curve.data_path.split('"')[1]
    index = list(head.data.shape_keys.key_blocks.keys()).index(block) - 1
    assert params["expr"][index] == pytest.approx(old + 3.0, abs=1e-6)


def test_render_animation_writes_images_and_files(scene, tmp_path):
    use_camera(next(iter(Capture.open(scene["capture"]).cameras)))
    start = bpy.context.scene.frame_start
    result = bpy.ops.mogaface.render_animation(frame_start=start, frame_end=start + 2, directory=str(tmp_path),
                                               file_format="BOTH")
    assert result == {"FINISHED"}
    camera = bpy.context.scene.camera.name
    for frame in range(start, start + 3):
        image = bpy.data.images[render_image_name(camera, frame)]
        assert image.packed_file is not None
        stem = f"{camera}_{frame:04d}".replace(" ", "_")
        # the files hold the image's pixels (the core render, as the test above checks), read back
        # by other readers: PNG as 8-bit sRGB (what "Standard" shows), EXR as scene-linear
        import OpenEXR
        from PIL import Image

        pixels = image_array(image)[::-1]
        png = np.asarray(Image.open(tmp_path / f"{stem}.png").convert("RGBA"), np.float32) / 255
        srgb = np.where(pixels[..., :3] > 0.0031308, 1.055 * pixels[..., :3] ** (1 / 2.4) - 0.055,
                        pixels[..., :3] * 12.92)
        assert np.abs(png[..., :3] - srgb).max() <= 0.6 / 255 and (png[..., 3] == 1).all()
        channels = OpenEXR.File(str(tmp_path / f"{stem}.exr")).channels()
        exr = np.stack([channels[c].pixels for c in "RGBA"], axis=2) if "R" in channels else \
            channels["RGBA"].pixels
        assert np.abs(exr - pixels).max() < 1e-6


def test_export_ply_writes_world_gaussians(scene, tmp_path):
    import trimesh

    path = tmp_path / "avatar.ply"
    assert bpy.ops.mogaface.export_ply(filepath=str(path)) == {"FINISHED"}
    cloud = trimesh.load(path)
    avatar = Avatar.load(scene["run"] / "avatar.pt")
    assert len(cloud.vertices) == len(avatar.gaussians)
    start = bpy.context.scene.frame_start
    ranged = tmp_path / "range.ply"
    assert bpy.ops.mogaface.export_ply(filepath=str(ranged), use_range=True, frame_start=start,
                                       frame_end=start + 1) == {"FINISHED"}
    assert sorted(p.name for p in tmp_path.glob("range_*.ply")) == [f"range_{start:04d}.ply",
                                                                  f"range_{start + 1:04d}.ply"]


def test_avatar_errors_are_reported(scene, tmp_path):
    with pytest.raises(RuntimeError, match="avatar file not found"):
        bpy.ops.mogaface.load_avatar(filepath=str(tmp_path))
    toy = tmp_path / "toy.npz"
    write_model_file(toy, make_toy_model(n_vertices=60, n_shape=4, n_expr=3))
    bpy.ops.mogaface.import_head(filepath=str(toy))
    with pytest.raises(RuntimeError, match="vertices"):
        bpy.ops.mogaface.load_avatar(filepath=str(scene["run"]))
    with pytest.raises(RuntimeError, match="not a head with an avatar"):
        bpy.ops.mogaface.render_frame(head=bpy.context.active_object.name)
    bpy.data.objects.remove(bpy.context.active_object)
    bpy.context.view_layer.objects.active = scene["head"]


def test_improve_tracking_keys_the_head_with_the_refined_tracking(scene, tmp_path):
    """The operator runs ``refine-tracking`` in a child process and keys what it wrote, on the
    tracker's frames; a failed job keeps the keys."""
    import shutil

    from mogaface.core.refiner.training import RefinerSettings, train_refiner

    run = tmp_path / "run"
    shutil.copytree(scene["run"], run)
    train_refiner(run, RefinerSettings(starts=2, offsets_per_start=2, gap_timesteps=2, threads=1,
                                       spec={"grid": 4, "render_limit": 64, "prior": 1.0, "gap_rank": 1}))
    head = scene["head"]
    bpy.context.view_layer.objects.active = head
    with pytest.raises(RuntimeError, match="not a finished run"):
        bpy.ops.mogaface.improve_tracking(run=str(tmp_path / "nothing"))
    original = read_tracking(scene["run"] / "flame_param")
    try:
        assert bpy.ops.mogaface.improve_tracking(run=str(run), passes=1, views=2, fit_steps=1) == {"FINISHED"}
        folder = run / "refined_tracking" / "flame_param"
        assert json.loads((run / "refined_tracking" / "refined_tracking.json").read_text())["fit_steps"] == 1
        assert bpy.context.scene.mogaface.tracking_folder == str(folder)
        refined = read_tracking(folder)
        assert len(refined.frames) == len(Capture.open(scene["capture"]).timesteps)
        keys = head.data.shape_keys.key_blocks
        n_expr = refined.params["expr"].shape[1]  # the head's expression keys follow Basis
        for index, frame in enumerate(refined.frames):
            bpy.context.scene.frame_set(int(frame))
            shown = np.array([keys[i + 1].value for i in range(n_expr)])
            np.testing.assert_allclose(shown, refined.params["expr"][index, :n_expr], atol=1e-5)
            for name, (prop, _) in POSE_PROPERTIES.items():
                np.testing.assert_allclose(np.array(head[prop]), refined.params[name][index], atol=1e-5)
        improving = importlib.import_module(MODULE + ".operators.improve_tracking")
        assert improving.last_progress().state == "done" and improving.current_worker() is None
        fcurves = head.data.shape_keys.animation_data.action.layers[0].strips[0].channelbags[0].fcurves
        expression_curves = [c for c in fcurves if "key_blocks" in c.data_path]
        assert {len(c.keyframe_points) for c in expression_curves} == {len(refined.frames)}  # old keys replaced
        assert len(original.frames) < len(refined.frames)  # the run tracked its training timesteps only
    finally:
        assert bpy.ops.mogaface.import_tracking(directory=str(scene["run"] / "flame_param")) == {"FINISHED"}


def test_headless_script_help():
    result = subprocess.run([sys.executable, str(SCRIPT), "--help"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and "--blend" in result.stdout and "--train" in result.stdout


def test_headless_script_builds_a_scene_that_reopens_with_everything(scene, tmp_path, handheld):
    """Trained, then driven by a performance clip (tracked with the avatar's shape), rendered, saved."""
    blend, frames = tmp_path / "scene.blend", tmp_path / "frames"
    env = {**os.environ, **{name: str(tmp_path / "user") for name in addon_test._USER_VARS}}
    result = subprocess.run(
        [sys.executable, str(SCRIPT), str(scene["capture"]), "--run", str(tmp_path / "run"), "--train",
         "--preset", "quick", "--steps", "5", "--blend", str(blend), "--render-dir", str(frames),
         "--frames", "2", "4", "--drive", str(handheld / "footage" / "clip.mp4"), "--drive-out",
         str(tmp_path / "performance"), "--fps", "15", "--fit-steps", "5", "--track-size", "112"],
        capture_output=True, text=True, timeout=180, env=env,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    performance = read_tracking(tmp_path / "performance")
    assert len(performance.frames) == 6  # 12 frames at 30 fps, retimed to the scene's 15
    assert sorted(p.name for p in frames.glob("*.png")) == [f"Camera_cam01_{f:04d}.png" for f in (2, 3, 4)]
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    cameras = [o for o in bpy.data.objects if o.type == "CAMERA"]
    assert len(cameras) == 3 and bpy.context.scene.camera.name == "Camera cam01"
    head = next(o for o in bpy.data.objects if AVATAR_PATH_PROPERTY in o)
    assert head.data.shape_keys.animation_data.action and head.animation_data.action
    images = [bpy.data.images[render_image_name("Camera cam01", f)] for f in (2, 3, 4)]
    assert all(image.packed_file is not None and tuple(image.size) == (48, 48) for image in images)
    assert image_array(images[0])[..., 3].max() > 0.5  # pixels survived the round trip
    assert bpy.context.scene.mogaface.tracking_folder == str(tmp_path / "performance")
    assert (bpy.context.scene.frame_start, bpy.context.scene.frame_end) == (1, 6)
    bpy.context.scene.frame_set(3)
    expr = np.array([head.data.shape_keys.key_blocks[i + 1].value for i in range(performance.params["expr"].shape[1])])
    np.testing.assert_allclose(expr, performance.params["expr"][2], atol=1e-5)  # the performance is what plays
    assert bpy.ops.mogaface.render_frame() == {"FINISHED"}


def test_headless_script_reports_errors(tmp_path):
    env = {**os.environ, **{name: str(tmp_path / "user") for name in addon_test._USER_VARS}}
    result = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path / "missing"), "--run", str(tmp_path / "run"),
         "--blend", str(tmp_path / "x.blend")],
        capture_output=True, text=True, timeout=60, env=env,
    )
    assert result.returncode == 1 and "error:" in result.stderr and "Traceback" not in result.stderr


def test_disabling_leaves_nothing_registered(scene):
    import addon_utils

    addon_utils.disable(MODULE, default_set=True)
    for name in (*addon_test.CLASS_NAMES, "MOGAFACE_OT_train_cancel"):
        assert not hasattr(bpy.types, name), name
    assert not hasattr(bpy.types.Scene, "mogaface")
    for handlers in (bpy.app.handlers.frame_change_post, bpy.app.handlers.depsgraph_update_post):
        assert not any(h.__module__.startswith(MODULE) for h in handlers)
    assert "mogaface" not in dir(bpy.ops)

