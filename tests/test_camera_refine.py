"""Per-camera extrinsic refinement: the scene motion equals the refined camera, a known calibration
error is recovered, the gauge holds, and the offsets survive checkpoints and reach the run folder."""

import dataclasses
import json

import numpy as np
import pytest
import torch
from test_evaluate_fixtures import tiny_capture_like

from mogaface.core.avatar.avatar import Avatar
from mogaface.core.correction.avatar import render_world
from mogaface.core.data.camera_file import read_cameras
from mogaface.core.data.capture import Capture
from mogaface.core.data.generator import perturb_camera
from mogaface.core.evaluate.camera_error import camera_errors, pose_error
from mogaface.core.train import config as C
from mogaface.core.train.camera_refine import CameraOffsets
from mogaface.core.train.checkpoint import latest_checkpoint, load_checkpoint
from mogaface.core.train.data import TrainingData
from mogaface.core.train.trainer import Trainer


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return tiny_capture_like(tmp_path_factory, "refine_capture", camera_noise=1.0)


@pytest.fixture(scope="module")
def scene(capture):
    """A fixed avatar with random flat colours (texture to align on) posed at the first training frame."""
    data = TrainingData(capture)
    avatar = Avatar.initial(capture / "head.pkl", 0)
    with torch.no_grad():
        avatar.gaussians.sh_dc.copy_(torch.rand(avatar.gaussians.sh_dc.shape, generator=torch.Generator().manual_seed(1)) - 0.5)
        avatar.gaussians.opacity_logit.fill_(3.0)
        frame = data.frames[0]
        world = avatar.gaussians.world(avatar.posed_vertices(data.flame_table().params(frame.timestep_index)),
                                       avatar.flame.faces)
    return data, {k: v.detach() for k, v in world.items()}


def offsets_for(cameras, gauge="none", rotation=None, translation=None):
    offsets = CameraOffsets(cameras, gauge)
    with torch.no_grad():
        for i in range(len(offsets.ids)):
            if rotation is not None:
                offsets.rotation[i].copy_(torch.as_tensor(rotation[i]))
            if translation is not None:
                offsets.translation[i].copy_(torch.as_tensor(translation[i]))
    return offsets


def test_moving_the_scene_renders_what_the_refined_camera_sees(scene):
    data, world = scene
    cameras = data.capture.cameras
    rng = np.random.default_rng(0)
    offsets = offsets_for(cameras, rotation=rng.normal(scale=0.02, size=(len(cameras), 3)),
                          translation=rng.normal(scale=0.01, size=(len(cameras), 3)))
    for cid in offsets.ids:
        with torch.no_grad():
            moved = render_world(offsets.move_scene(world, cid), cameras[cid], data.background).rgb
            direct = render_world(world, offsets.refined_camera(cid), data.background).rgb
            calibrated = render_world(world, cameras[cid], data.background).rgb
        assert (moved - calibrated).abs().max() > 0.2  # the offset is visible
        assert (moved - direct).abs().max() < 2e-3, cid


def test_a_known_calibration_error_of_one_camera_is_recovered(scene):
    data, world = scene
    truth = data.capture.cameras
    cid = sorted(truth)[0]
    wrong = perturb_camera(truth[cid], 1.5, np.random.default_rng(5))
    start_rotation, _ = pose_error(wrong, truth[cid])
    assert start_rotation > 1.0
    with torch.no_grad():
        target = render_world(world, truth[cid], data.background).rgb
    offsets = CameraOffsets({cid: wrong}, gauge="none")
    optimizer = torch.optim.Adam([{"params": list(offsets.rotation), "lr": 3e-3},
                                  {"params": list(offsets.translation), "lr": 3e-4}])
    for step in range(80):
        if step == 50:
            for group in optimizer.param_groups:
                group["lr"] *= 0.2
        rgb = render_world(offsets.move_scene(world, cid), wrong, data.background).rgb
        loss = (rgb - target).abs().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    refined = offsets.refined_camera(cid)
    rotation, _ = pose_error(refined, truth[cid])
    assert rotation < 0.3 * start_rotation, (start_rotation, rotation)
    # Where the head lands in the image: what the render can see (the centre's depth it cannot,
    # at 48² and this field of view, so the centre distance is not asserted).
    points = world["means"].double().numpy()
    def pixels(camera):
        return camera.project(points)[0]
    start_pixels = np.linalg.norm(pixels(wrong) - pixels(truth[cid]), axis=1).mean()
    end_pixels = np.linalg.norm(pixels(refined) - pixels(truth[cid]), axis=1).mean()
    assert start_pixels > 2.0 and end_pixels < 0.15 * start_pixels, (start_pixels, end_pixels)


def test_mean_gauge_keeps_the_offsets_centred(capture):
    cameras = Capture.open(capture).cameras
    rng = np.random.default_rng(2)
    offsets = offsets_for(cameras, "mean", rng.normal(size=(len(cameras), 3)), rng.normal(size=(len(cameras), 3)))
    before = offsets.values()
    offsets.fix_gauge()
    rotation, translation = offsets.values()
    assert torch.allclose(rotation.mean(0), torch.zeros(3), atol=1e-6)
    assert torch.allclose(translation.mean(0), torch.zeros(3), atol=1e-6)
    assert torch.allclose(rotation - rotation[0], before[0] - before[0][0], atol=1e-6)  # differences kept
    free = offsets_for(cameras, "none", before[0].numpy(), before[1].numpy())
    free.fix_gauge()
    assert torch.equal(free.values()[0], before[0])
    with pytest.raises(ValueError, match="'first'"):
        CameraOffsets(cameras, "first")


def _rig_moved(cameras, rotation, shift):
    """Every camera moved by one rigid motion of the whole rig: turned by ``rotation`` (axis-angle)
    about the world origin, then shifted."""
    from mogaface.core.flame.lbs import axis_angle_to_matrix

    turn = axis_angle_to_matrix(torch.as_tensor(rotation, dtype=torch.float64)).numpy()
    moved = {}
    for cid, camera in cameras.items():
        c2w = np.linalg.inv(camera.w2c)
        c2w[:3, :3] = turn @ c2w[:3, :3]
        c2w[:3, 3] = turn @ c2w[:3, 3] + np.asarray(shift)
        moved[cid] = dataclasses.replace(camera, w2c=np.linalg.inv(c2w))
    return moved


def test_rigid_gauge_removes_a_motion_of_the_whole_rig_and_keeps_the_rest(capture):
    cameras = Capture.open(capture).cameras
    offsets = CameraOffsets(cameras, "rigid")
    offsets.start_from(_rig_moved(cameras, [0.006, -0.01, 0.004], [0.004, -0.003, 0.006]))  # ~0.7°, 8 mm
    assert max(pose_error(offsets.refined_camera(c), cameras[c])[0] for c in cameras) > 0.5
    offsets.fix_gauge()
    for cid in cameras:  # back to the calibration, to second order in the angle
        angle, centre = pose_error(offsets.refined_camera(cid), cameras[cid])
        assert angle < 0.01 and centre < 0.1, (cid, angle, centre)
    rng = np.random.default_rng(4)
    kept = offsets_for(cameras, "rigid", rng.normal(size=(len(cameras), 3)) * 0.01,
                       rng.normal(size=(len(cameras), 3)) * 0.005)
    kept.fix_gauge()
    rotation, translation = kept.values()
    again = offsets_for(cameras, "rigid", rotation.numpy(), translation.numpy())
    again.fix_gauge()
    assert torch.allclose(torch.cat(again.values()), torch.cat(kept.values()), atol=1e-7)  # nothing rigid left
    # a rigid motion added (to first order) is removed exactly: the same offsets come back
    omega, shift = np.array([0.01, 0.02, -0.01]), np.array([0.003, 0.0, -0.002])
    centres = offsets.centres.double().numpy()
    both = offsets_for(cameras, "rigid", rotation.numpy() + omega, translation.numpy() + np.cross(omega, centres) + shift)
    both.fix_gauge()
    assert torch.allclose(torch.cat(both.values()), torch.cat(kept.values()), atol=1e-6)
    assert rotation.abs().max() > 0.005  # what is not a rigid motion stays (the mean gauge would centre it)
    turn = offsets_for(cameras, "rigid", np.tile([0.0, 0.01, 0.0], (len(cameras), 1)))  # every camera turned alike
    turn.fix_gauge()
    assert turn.values()[0][:, 1].mean() > 0.002  # ... about its own centre: partly kept, the images pin it


def refine_config(**train):
    return C.resolve(overrides={
        "train": {"steps": 10, "threads": 1, "log_every": 5, "checkpoint_every": 0, **train},
        "densify": {"start": 2, "stop": 8, "interval": 3, "grad_threshold": 1e-6, "opacity_reset_interval": 0,
                    "sh_degree_interval": 4},
        "eval": {"at_end": False, "lpips": False},
        "cameras": {"refine": True, "rotation_lr": 1e-3, "translation_lr": 1e-4, "begin": 0.0},
    })


def test_training_refines_checkpoints_resumes_and_writes_the_cameras(capture, tmp_path):
    config = refine_config()
    straight, split = tmp_path / "straight", tmp_path / "split"
    Trainer(capture, straight, config).run()
    assert Trainer(capture, split, config).run(until=4)["step"] == 4
    assert "cameras" in load_checkpoint(latest_checkpoint(split / "checkpoints"))
    Trainer(capture, split, resume=True).run()
    a, b = (load_checkpoint(latest_checkpoint(run / "checkpoints"))["cameras"] for run in (straight, split))
    assert a["ids"] == b["ids"] == sorted({f.camera_id for f in Capture.open(capture).frames("train")})
    for key in ("rotation", "translation"):
        assert a[key].abs().max() > 0, key
        assert torch.equal(a[key], b[key]), key
    trained = {cid: Capture.open(capture).cameras[cid] for cid in a["ids"]}
    rigid = offsets_for(trained, "rigid", a["rotation"].numpy(), a["translation"].numpy())
    rigid.fix_gauge()  # the default gauge held through training: nothing rigid left to remove
    assert torch.allclose(torch.cat(rigid.values()), torch.cat([a["rotation"], a["translation"]]), atol=1e-6)
    written = read_cameras(straight / "cameras_refined.json")
    offsets = CameraOffsets({cid: written[cid] for cid in a["ids"]})
    calibrated = Capture.open(capture).cameras
    assert sorted(written) == a["ids"]
    for i, cid in enumerate(a["ids"]):
        assert np.allclose(written[cid].K, calibrated[cid].K)
        refined = CameraOffsets({cid: calibrated[cid]})
        with torch.no_grad():
            refined.rotation[0].copy_(a["rotation"][i])
            refined.translation[0].copy_(a["translation"][i])
        assert np.allclose(written[cid].w2c, refined.refined_camera(cid).w2c, atol=1e-9)
        assert not np.allclose(written[cid].w2c, calibrated[cid].w2c, atol=1e-7)
    errors = camera_errors(Capture.open(capture), straight)
    assert errors["refined"]["cameras"] == errors["calibrated_refined_cameras"]["cameras"] == len(a["ids"])
    assert json.loads((straight / "run.json").read_text())["cameras_refined"] is True
    assert offsets.ids == a["ids"]


def test_by_default_only_the_rotations_are_stepped_and_the_centres_move_with_the_rig(capture, tmp_path):
    """The default steps the rotations alone (the images pin the centres too weakly:
    docs/notebook/2026-11-26-camera-refinement.md); the
    rigid motion the gauge takes out of the rotations reaches the centres as one rigid motion."""
    config = refine_config()
    defaults = C.resolve().cameras
    config.cameras.rotation_lr, config.cameras.translation_lr = defaults.rotation_lr, defaults.translation_lr
    Trainer(capture, tmp_path / "run", config).run()
    state = load_checkpoint(latest_checkpoint(tmp_path / "run" / "checkpoints"))["cameras"]
    assert state["rotation"].abs().max() > 1e-4
    calibrated = Capture.open(capture).cameras
    centres = np.stack([calibrated[cid].center for cid in state["ids"]])
    # every centre shift is ω₀ × c_i + t₀ for one (ω₀, t₀): a rigid motion of the rig, nothing per camera
    basis = np.stack([np.stack([np.cross(np.eye(3)[k], c) for k in range(3)], 1) for c in centres])
    basis = np.concatenate([basis, np.tile(np.eye(3), (len(centres), 1, 1))], 2).reshape(-1, 6)
    shifts = state["translation"].double().numpy().reshape(-1)
    fitted = basis @ np.linalg.lstsq(basis, shifts, rcond=None)[0]
    assert np.abs(shifts - fitted).max() < 1e-6
    assert np.abs(shifts).max() > 1e-6  # the rigid gauge moves even measured centres
    # gauge none (measured centres): the cameras only turn, every centre stays where it was measured
    config.cameras.gauge = "none"
    Trainer(capture, tmp_path / "measured", config).run()
    state = load_checkpoint(latest_checkpoint(tmp_path / "measured" / "checkpoints"))["cameras"]
    assert state["rotation"].abs().max() > 1e-4 and not state["translation"].any()


def test_camera_rates_decay_to_their_final_ratio(capture, tmp_path):
    from mogaface.core.train.schedule import camera_lrs

    config = refine_config(steps=6)
    config.cameras.final_ratio = 0.01
    assert camera_lrs(config, 0) == {"cameras.rotation": 1e-3, "cameras.translation": 1e-4, "cameras.delay": 1e-2,
                                     "cameras.colour": 1e-3}
    assert camera_lrs(config, 3)["cameras.rotation"] == pytest.approx(1e-4)  # halfway: the geometric mean
    assert camera_lrs(config, 6)["cameras.translation"] == pytest.approx(1e-6)
    trainer = Trainer(capture, tmp_path / "run", config)
    trainer.run(until=4)
    used = {g["name"]: g["lr"] for g in trainer.optimizer.param_groups if g["name"].startswith("cameras.")}
    assert set(used) == {"cameras.rotation", "cameras.translation"}  # no delays asked for
    assert used == pytest.approx({k: camera_lrs(config, 3)[k] for k in used})  # the last step (3) ran at its rate


def test_resuming_a_refining_run_without_offsets_is_refused(capture, tmp_path):
    run = tmp_path / "run"
    Trainer(capture, run, refine_config(steps=3)).run(until=2)
    path = latest_checkpoint(run / "checkpoints")
    state = load_checkpoint(path)
    del state["cameras"]
    from mogaface.core.io.torch_file import save_torch_state

    save_torch_state(state, path)
    with pytest.raises(Exception, match="camera offsets"):
        Trainer(capture, run, resume=True)


def test_camera_settings_are_checked():
    with pytest.raises(Exception, match="cameras.gauge"):
        C.resolve(overrides={"cameras": {"gauge": "first"}})
    with pytest.raises(Exception, match="cameras.rotation_lr"):
        C.resolve(overrides={"cameras": {"rotation_lr": 5.0}})
    with pytest.raises(Exception, match="cameras.settle_steps"):
        C.resolve(overrides={"cameras": {"refine": True, "settle_steps": 5}})  # no first avatar to align to
    with pytest.raises(Exception, match="cameras.settle_at"):
        C.resolve(overrides={"cameras": {"settle_at": -1}})
    with pytest.raises(Exception, match="cameras.settle_at.*step 450"):  # the cameras would not move yet
        C.resolve(overrides={"train": {"steps": 1000}, "cameras": {"refine": True, "begin": 0.45, "settle_at": 300,
                                                                   "settle_steps": 100}})
    with pytest.raises(Exception, match="cameras.begin"):
        C.resolve(overrides={"cameras": {"begin": 1.0}})


def test_in_the_cameras_only_phase_only_the_cameras_move(capture, tmp_path):
    config = refine_config(steps=8)
    config.cameras.settle_at, config.cameras.settle_steps = 3, 3
    config.flame.finetune = True  # the per-timestep parameters hold still too
    trainer = Trainer(capture, tmp_path / "run", config)

    def state():
        tensors = {k: v.detach().clone() for k, v in trainer.avatar.gaussians.tensors().items()}
        tensors.update({f"table.{i}": p.detach().clone() for i, p in enumerate(trainer.table.parameters())})
        return tensors, torch.cat(trainer.camera_offsets.values()).clone()

    def moved(before, after):
        return [k for k in before[0] if before[0][k].shape != after[0][k].shape
                or not torch.equal(before[0][k], after[0][k])]

    history = [state()]
    for _ in range(7):
        trainer.train_step()
        history.append(state())
    for step in (3, 4, 5):  # steps 3..5 settle
        assert moved(history[step], history[step + 1]) == [], step
        assert not torch.equal(history[step][1], history[step + 1][1]), step
    for step in (1, 6):
        assert "local_position" in moved(history[step], history[step + 1]), step
    assert any(k.startswith("table.") for k in moved(history[1], history[2]))


def test_the_cameras_hold_still_until_their_first_step(capture, tmp_path):
    config = refine_config(steps=6)
    config.cameras.begin = 0.5
    trainer = Trainer(capture, tmp_path / "run", config)
    history = [torch.cat(trainer.camera_offsets.values()).clone()]
    for _ in range(5):
        trainer.train_step()
        history.append(torch.cat(trainer.camera_offsets.values()).clone())
    assert all(torch.equal(offsets, history[0]) for offsets in history[:4])  # steps 0..2 hold
    assert not torch.equal(history[3], history[5])  # from step 3 they move
    rotations = {g["name"]: g for g in trainer.optimizer.param_groups}["cameras.rotation"]["params"]
    taken = sum(int(trainer.optimizer.state.get(p, {}).get("step", 0)) for p in rotations)
    assert taken == 2  # steps 3 and 4, one camera each: Adam's moments start at ``begin``


def test_a_new_round_starts_from_the_refined_cameras_of_the_last(capture, tmp_path):
    first = tmp_path / "first"
    Trainer(capture, first, refine_config(steps=6)).run()
    written = read_cameras(first / "cameras_refined.json")
    config = refine_config(steps=2)
    config.cameras.start = str(first / "cameras_refined.json")
    second = Trainer(capture, tmp_path / "second", config)
    for cid, camera in second.camera_offsets.refined_cameras().items():
        np.testing.assert_allclose(camera.w2c, written[cid].w2c, atol=1e-6)  # offsets in float32
    assert second.camera_offsets.values()[0].abs().max() > 0
    calibrated = Capture.open(capture).cameras
    rng = np.random.default_rng(0)
    turned = {cid: perturb_camera(c, 40.0, rng) for cid, c in calibrated.items()}  # far beyond small angles
    offsets = CameraOffsets(calibrated)
    offsets.start_from(turned)
    for cid, camera in offsets.refined_cameras().items():
        np.testing.assert_allclose(camera.w2c, turned[cid].w2c, atol=1e-6)
    resized = {cid: dataclasses.replace(c, width=c.width + 1) for cid, c in written.items()}
    with pytest.raises(Exception, match="intrinsics or image size"):
        CameraOffsets(calibrated).start_from(resized)
    with pytest.raises(Exception, match="cameras.start"):
        C.resolve(overrides={"cameras": {"start": "x.json"}})


def test_rounds_train_fresh_avatars_from_the_last_rounds_cameras_and_resume(capture, tmp_path):
    from mogaface.core.cli import main
    from mogaface.core.train.rounds import round_config, round_folder

    run = tmp_path / "run"
    config = refine_config(steps=4)
    config.cameras.rounds = 3
    config.cameras.begin = 0.5  # the last round's: the earlier ones move their cameras from the first step
    settings = tmp_path / "rounds.toml"
    settings.write_text(C.to_toml(config))
    # round 1 was stopped half-way: it resumes, round 2 starts from its cameras, the last is RUN itself
    Trainer(capture, round_folder(run, 1), round_config(config, "")).run(until=2)
    assert main(["train", str(capture), "--out", str(run), "--config", str(settings), "--quiet"]) == 0
    for k in (1, 2):
        assert (round_folder(run, k) / "avatar.pt").exists() and not (round_folder(run, k) / "metrics.json").exists()
    first = [json.loads(line) for line in (round_folder(run, 1) / "events.jsonl").read_text().splitlines()]
    assert "resume" in [e["event"] for e in first]
    second = C.load(round_folder(run, 2) / "config.toml")
    assert second.cameras.start == str((round_folder(run, 1) / "cameras_refined.json").resolve())
    assert second.cameras.begin == 0
    last = C.load(run / "config.toml")
    assert last.cameras.start == str((round_folder(run, 2) / "cameras_refined.json").resolve())
    assert last.cameras.begin == 0.5
    final = read_cameras(run / "cameras_refined.json")
    assert any(not np.allclose(final[c].w2c, Capture.open(capture).cameras[c].w2c, atol=1e-6) for c in final)
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    stages = [e.get("stage") for e in events if e["event"] == "iter"]
    assert stages[0] == "camera round 1/3" and "camera round 2/3" in stages and stages[-1] is None


def test_a_time_budget_is_shared_by_the_rounds_and_a_resume_divides_it_once(capture, tmp_path):
    import shutil

    from mogaface.core.cli import main
    from mogaface.core.train.rounds import ROUNDS_DIR, round_folder

    run = tmp_path / "run"
    config = refine_config(steps=3, max_minutes=30.0)  # the steps end it; the budget is what is shared
    config.cameras.rounds = 3
    settings = tmp_path / "rounds.toml"
    settings.write_text(C.to_toml(config))
    assert main(["train", str(capture), "--out", str(run), "--config", str(settings), "--quiet"]) == 0
    assert C.load(run / ROUNDS_DIR / "config.toml").train.max_minutes == 30.0  # the whole run's
    for folder in (round_folder(run, 1), round_folder(run, 2), run):
        assert C.load(folder / "config.toml").train.max_minutes == 10.0
    # the last round stopped before its first checkpoint: its settings come again from the whole run's
    shutil.rmtree(run / "checkpoints")
    (run / "avatar.pt").unlink()
    assert main(["train", str(capture), "--out", str(run), "--resume", "--quiet"]) == 0
    assert C.load(run / "config.toml").train.max_minutes == 10.0
    assert C.load(run / "config.toml").cameras.start == str((round_folder(run, 2) / "cameras_refined.json").resolve())
