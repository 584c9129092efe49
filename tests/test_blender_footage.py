"""Track Footage and Drive from Footage in the real Blender (bpy module): the clip tracked in a child
process, then the camera, the keyed head and the footage behind it; a second run of the clip keys a
head's face at the scene's frame rate, thinned within the tolerance."""

import importlib
import json

import test_blender_addon as addon_test  # sets Blender's user folders to a temporary one first

# isort: split

import bpy  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from mogaface.core.for_blender.head_rig import POSE_PROPERTIES  # noqa: E402
from mogaface.core.for_blender.tracking import read_tracking  # noqa: E402

MODULE = addon_test.MODULE


@pytest.fixture(scope="module")
def tracked(tmp_path_factory, handheld):
    root = tmp_path_factory.mktemp("blender_footage")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon_test.build_and_install(root / "dist")
    clip = handheld / "footage" / "clip.mp4"
    result = bpy.ops.mogaface.track_footage(filepath=str(clip), out=str(root / "capture"), size=112, fit_steps=10,
                                            photometric_steps=20)  # briefly: the plumbing, not the fit
    return {"root": root, "clip": clip, "capture": root / "capture", "result": result,
            "head": bpy.context.view_layer.objects.active}


def shown(head, frame: int, n_expr: int) -> dict:
    bpy.context.scene.frame_set(frame)
    keys = head.data.shape_keys.key_blocks
    values = {"expr": np.array([keys[i + 1].value for i in range(n_expr)])}
    values.update({name: np.array(head[prop]) for name, (prop, _) in POSE_PROPERTIES.items()})
    return values


def test_track_footage_brings_the_camera_the_keyed_head_and_the_movie(tracked):
    assert tracked["result"] == {"FINISHED"}
    scene, head = bpy.context.scene, tracked["head"]
    assert scene.mogaface.capture_folder == str(tracked["capture"])
    tracking = read_tracking(tracked["capture"] / "flame_param")
    assert (scene.frame_start, scene.frame_end) == (1, 12) and scene.render.fps == 30
    n_expr = tracking.params["expr"].shape[1]
    for index in (0, 7):
        values = shown(head, int(tracking.frames[index]), n_expr)
        for name, value in values.items():
            np.testing.assert_allclose(value, tracking.params[name][index], atol=1e-5)
    background = scene.camera.data.background_images[0]
    assert background.source == "MOVIE_CLIP" and background.clip.frame_start == 1  # input frame 0 on scene frame 1
    assert background.clip.filepath == str(tracked["clip"]) and scene.camera.data.show_background_images
    footage = importlib.import_module(MODULE + ".operators.footage")
    assert footage.last_progress().state == "done" and footage.current_worker() is None
    assert not [m for m in scene.timeline_markers if m.name == footage.LOST_MARKER]  # the clip never loses the face
    report = json.loads((tracked["capture"] / "tracking.json").read_text())
    assert (report["fit_steps"], report["photometric_steps"]) == (10, 20)  # the panel's Skin Steps reached the child


def test_lost_frames_become_markers_and_a_report_line(tracked):
    footage = importlib.import_module(MODULE + ".operators.footage")
    scene = bpy.context.scene
    footage.mark_lost_frames(scene, [5, 6])
    footage.mark_lost_frames(scene, [9])  # a new tracking replaces the old marks
    assert [(m.name, m.frame) for m in scene.timeline_markers] == [(footage.LOST_MARKER, 9)]
    assert "no face in 2 frames (5, 6" in footage.lost_text([4, 5])
    footage.mark_lost_frames(scene, [])


def test_footage_comes_from_a_movie_clip_of_the_file_or_the_files_picked(tracked):
    from types import SimpleNamespace

    footage = importlib.import_module(MODULE + ".operators.footage")
    clip = bpy.data.movieclips.load(str(tracked["clip"]), check_existing=True)
    picked = SimpleNamespace(movie_clip=clip.name, directory="", files=[], filepath="")
    assert footage.footage_paths(picked) == [str(tracked["clip"])]
    photos = SimpleNamespace(movie_clip="", directory="/photos/", filepath="/photos/a.jpg",
                             files=[SimpleNamespace(name="a.jpg"), SimpleNamespace(name="b.jpg")])
    assert footage.footage_paths(photos) == ["/photos/a.jpg", "/photos/b.jpg"]
    photos.files = []
    assert footage.footage_paths(photos) == ["/photos/a.jpg"]


def test_several_clips_picked_become_cameras_the_scene_switches_between(tracked):
    """Two videos picked in the browser: one capture, each clip behind its own camera from its
    first timestep on, and a marker bound to that camera there (the scene's camera follows)."""
    import shutil

    footage = importlib.import_module(MODULE + ".operators.footage")
    folder = tracked["root"] / "clips"  # kept for the module: the head it brings is posed from its folder
    folder.mkdir()
    for name in ("a.mp4", "b.mp4"):
        shutil.copyfile(tracked["clip"], folder / name)
    result = bpy.ops.mogaface.track_footage(directory=str(folder) + "/", files=[{"name": "a.mp4"}, {"name": "b.mp4"}],
                                            out=str(tracked["root"] / "two_clips"), size=112, fit_steps=10,
                                            photometric_steps=20)
    assert result == {"FINISHED"}
    scene = bpy.context.scene
    assert (scene.frame_start, scene.frame_end) == (1, 24)
    markers = sorted((m.frame, m.name, m.camera["mogaface_camera_id"]) for m in scene.timeline_markers
                     if m.name.startswith(footage.CLIP_MARKER + " "))
    assert markers == [(1, "clip 1: a.mp4", "cam00"), (13, "clip 2: b.mp4", "cam01")]
    for frame, _, camera_id in markers:
        scene.frame_set(frame)
        camera = scene.camera
        assert camera["mogaface_camera_id"] == camera_id
        clip = camera.data.background_images[0].clip
        assert clip.filepath == str(folder / f"{'ab'[frame > 1]}.mp4") and clip.frame_start == frame  # input frame 0
    footage.show_clips(scene, {"clips": [], "input_frames": []})  # a later tracking's markers replace these
    assert not [m for m in scene.timeline_markers if m.name.startswith(footage.CLIP_MARKER + " ")]
    bpy.context.view_layer.objects.active = tracked["head"]


def test_drive_from_footage_keys_the_performance_at_the_scene_rate(tracked, tmp_path):
    scene, head = bpy.context.scene, tracked["head"]
    scene.render.fps, scene.render.fps_base = 24, 1.0
    rest = np.array(head["mogaface_rotation"])
    out = tmp_path / "performance"
    assert bpy.ops.mogaface.drive_from_footage(filepath=str(tracked["clip"]), out=str(out), tolerance=0.002,
                                               keep_head_still=True, size=112, fit_steps=10,
                                               photometric_steps=20) == {"FINISHED"}
    performance = read_tracking(out)
    assert len(performance.frames) == 9  # 12 frames at 30 fps span 0.37 s: 9 frames at 24 fps
    assert (scene.frame_start, scene.frame_end) == (1, 9)
    n_expr = performance.params["expr"].shape[1]
    for index in range(9):
        values = shown(head, int(performance.frames[index]), n_expr)
        for name, value in values.items():
            np.testing.assert_allclose(value, performance.params[name][index], atol=2e-5)
        np.testing.assert_allclose(values["rotation"], rest, atol=1e-6)  # the head kept still
    curves = head.data.shape_keys.animation_data.action.layers[0].strips[0].channelbags[0].fcurves
    counts = [len(c.keyframe_points) for c in curves if "key_blocks" in c.data_path]
    assert min(counts) >= 2 and sum(counts) < 9 * len(counts)  # thinned, the ends kept
    assert np.ptp(performance.params["expr"], axis=0).max() > 1e-3  # the face moves


def test_footage_errors_are_reported(tracked, tmp_path):
    with pytest.raises(RuntimeError, match="pick a video file"):
        bpy.ops.mogaface.track_footage(filepath=str(tmp_path / "missing.mp4"))
    camera = bpy.context.scene.camera
    bpy.context.view_layer.objects.active = camera
    with pytest.raises(RuntimeError, match="not a MoGaFace head"):
        bpy.ops.mogaface.drive_from_footage(filepath=str(tracked["clip"]))
    bpy.context.view_layer.objects.active = tracked["head"]


def test_cancel_stops_the_tracking_child_and_leaves_no_capture(tracked, tmp_path):
    """The panel's Cancel sends the child SIGINT: it stops where it is (here in a long fit), and the folder
    has no split file (no reader takes it; Track Footage on the same folder resumes from its detections)."""
    import time

    from mogaface.core.for_blender.worker import FootageWorker, track_command

    out = tmp_path / "capture"
    worker = FootageWorker(track_command(None, [tracked["clip"]], out, tmp_path, size=112, fit_steps=5000), tmp_path)
    worker.start()
    started = time.monotonic()
    while worker.poll().step < 1 and not worker.progress.finished and time.monotonic() - started < 60:
        time.sleep(0.05)
    worker.cancel()
    progress = worker.wait(interval=0.1, timeout=60)
    assert progress.state == "cancelled", progress
    assert out.is_dir() and not (out / "transforms_train.json").exists()


def test_skin_steps_reach_both_children_unless_left_to_the_footage():
    from mogaface.core.for_blender.worker import drive_command, track_command

    track = track_command(None, ["a.mp4"], "out", "job", photometric_steps=0)
    drive = drive_command(None, "a.mp4", "identity.npz", "out", "job", photometric_steps=300)
    assert track[track.index("--photometric-steps") + 1] == "0" and drive[drive.index("--photometric-steps") + 1] == "300"
    assert "--photometric-steps" not in track_command(None, ["a.mp4"], "out", "job")  # the footage's chosen count


def test_disabling_leaves_no_footage_operator(tracked):
    import addon_utils

    addon_utils.disable(MODULE, default_set=True)
    for name in ("MOGAFACE_OT_track_footage", "MOGAFACE_OT_drive_from_footage", "MOGAFACE_OT_footage_cancel"):
        assert not hasattr(bpy.types, name), name
