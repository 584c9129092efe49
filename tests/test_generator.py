"""The synthetic capture generator: layout, splits, ground truth, noise, determinism."""

import hashlib
import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from scipy import ndimage

from mogaface.core.data.capture import Capture
from mogaface.core.data.generator import CaptureSettings, camera_dome, make_capture, perturb_camera
from mogaface.core.data.sequences import GroupNoise, TrackingNoise, add_tracking_noise, make_sequences, tracking_biases
from mogaface.core.data.validate import validate_capture
from mogaface.core.errors import InputError
from mogaface.core.flame.model import FlameModel
from mogaface.core.io.npz import load_npz

TINY = CaptureSettings(views=4, timesteps=16, size=64, supersample=2, camera_noise=0.0, seed=3)


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    return make_capture(tmp_path_factory.mktemp("capture"), TINY, progress=False)


def test_capture_validates_with_the_documented_splits(tiny_capture):
    summary = validate_capture(tiny_capture)
    info = json.loads((tiny_capture / "capture_info.json").read_text())
    assert summary.views == 4 and summary.timesteps == 16 + 2  # the validation sequence comes on top
    assert set(summary.sequences) == {"EXP-1", "EXP-2", "SPEECH", "FREE", "VAL"}
    assert info["sequences"]["FREE"] == [12, 16] and info["sequences"]["VAL"] == [16, 18]
    assert info["test_sequence"] == "FREE" and info["val_sequence"] == "VAL"
    capture = Capture.open(tiny_capture)
    val_cameras = {f.camera_id for f in capture.frames("val")}
    assert val_cameras == {info["val_camera"]}
    assert {f.sequence for f in capture.frames("test")} == {"FREE", "VAL"}  # neither is trained on
    assert len({f.camera_id for f in capture.frames("test")}) == 4
    assert len([f for f in capture.frames("test") if f.sequence == "VAL"]) == 2 * 4
    train = capture.frames("train")
    assert info["val_camera"] not in {f.camera_id for f in train}
    assert not {"FREE", "VAL"} & {f.sequence for f in train}
    # Novel-view frames use exactly the training timesteps.
    assert {f.timestep_index for f in capture.frames("val")} == {f.timestep_index for f in train}


def test_val_camera_is_frontal_and_rig_spans_both_profiles():
    vertices = np.random.default_rng(0).normal(scale=0.08, size=(100, 3))
    cameras, frontal = camera_dome(16, 256, vertices, np.random.default_rng(1))
    centres = np.array([c.center for c in cameras])
    azimuth = np.degrees(np.arctan2(centres[:, 0], centres[:, 2]))
    assert len(cameras) == 16 and abs(azimuth[frontal]) < 3
    assert azimuth.min() < -80 and azimuth.max() > 80
    assert (centres[:, 1] > 0.2).sum() >= 3 and (centres[:, 1] < -0.15).sum() >= 3  # above and below
    distances = np.linalg.norm(centres, axis=1)
    assert np.all(np.abs(distances - 1.0) < 0.15)
    assert len({round(c.fx, 3) for c in cameras}) == 16  # per-camera intrinsics


def test_every_vertex_projects_inside_the_mask(tiny_capture):
    capture = Capture.open(tiny_capture)
    model = FlameModel.load(tiny_capture / "head.pkl")
    inside = total = 0
    farthest = 0.0
    for frame in capture.frames("train")[:6]:
        gt = load_npz(tiny_capture / "flame_param_gt" / f"{frame.timestep_index:05d}.npz")
        params = {k: torch.from_numpy(np.asarray(v, dtype=np.float32).reshape(1, -1)) for k, v in gt.items()}
        with torch.no_grad():
            vertices = model(**params)[0].double().numpy()
        # The json camera is the true one when camera noise is off.
        uv, depth = capture.camera(frame).project(vertices)
        _, mask = capture.load_image(frame)
        cols, rows = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        ok = (depth > 0) & (cols >= 0) & (cols < 64) & (rows >= 0) & (rows < 64)
        inside += int((mask[rows[ok], cols[ok]] > 0).sum())
        total += int(ok.sum())
        # Pixels a silhouette edge grazes between samples read 0: allow them, nothing farther.
        farthest = max(farthest, float(ndimage.distance_transform_edt(mask == 0)[rows[ok], cols[ok]].max()))
    assert total > 1000 and inside / total > 0.97
    assert farthest <= 1.0


def test_tracked_parameters_are_truth_plus_configured_noise(tiny_capture):
    settings = json.loads((tiny_capture / "capture_info.json").read_text())["settings"]
    diffs = {"expr": [], "jaw_pose": []}
    for t in range(16):
        tracked = load_npz(tiny_capture / "flame_param" / f"{t:05d}.npz")
        truth = load_npz(tiny_capture / "flame_param_gt" / f"{t:05d}.npz")
        np.testing.assert_array_equal(tracked["shape"], truth["shape"])
        for key in diffs:
            diffs[key].append(tracked[key] - truth[key])
    expected = np.hypot(settings["expr_noise"], settings["expr_bias"])  # drift and bias add up
    assert abs(np.concatenate(diffs["expr"]).std() - expected) < 0.3 * expected
    assert np.concatenate(diffs["jaw_pose"]).std() < 3 * np.hypot(settings["pose_noise"], settings["pose_bias"])


LONG = 20000


def _zeros(length=LONG):
    return {k: np.zeros((length, n), np.float32) for k, n in
            [("shape", 5), ("expr", 40), ("rotation", 3), ("neck_pose", 3), ("jaw_pose", 3), ("eyes_pose", 6),
             ("translation", 3)]}


def _autocorrelation(errors: np.ndarray, lag: int) -> float:
    centred = errors - errors.mean(0)
    return float(np.mean([np.corrcoef(centred[:-lag, c], centred[lag:, c])[0, 1] for c in range(errors.shape[1])]))


def test_correlated_noise_has_the_asked_autocorrelation_and_bias():
    noise = TrackingNoise(expr=GroupNoise(0.4, correlation=5.0, bias=0.3), pose=GroupNoise(0.008, correlation=10.0),
                          translation=GroupNoise(0.0008, correlation=0.0, bias=0.001))
    rng = np.random.default_rng(0)
    params = _zeros()
    biases = tracking_biases(params, noise, rng)
    noisy = add_tracking_noise(params, noise, rng, biases)
    expr = noisy["expr"]
    # The constant part is the bias, drawn with the asked spread; the rest drifts with the asked std.
    np.testing.assert_allclose(expr.mean(0), biases["expr"], atol=0.05)
    assert 0.2 < biases["expr"].std() < 0.4
    assert abs((expr - expr.mean(0)).std() - 0.4) < 0.02
    for lag in (1, 5, 10):
        assert abs(_autocorrelation(expr, lag) - np.exp(-lag / 5.0)) < 0.05, lag
        assert abs(_autocorrelation(noisy["jaw_pose"], lag) - np.exp(-lag / 10.0)) < 0.08, lag
    assert abs(noisy["jaw_pose"].std() - 0.008) < 0.002 and np.allclose(biases["jaw_pose"], 0.0)
    # Translation: independent per timestep around its bias.
    assert abs(_autocorrelation(noisy["translation"], 1)) < 0.03
    np.testing.assert_allclose(noisy["translation"].mean(0), biases["translation"], atol=3e-5)
    np.testing.assert_array_equal(noisy["shape"], 0.0)


def test_iid_noise_statistics_over_many_timesteps():
    rng = np.random.default_rng(0)
    iid = CaptureSettings(**CaptureSettings.iid_noise(expr_noise=0.3, pose_noise=0.02, translation_noise=0.002))
    noisy = add_tracking_noise(_zeros(4000), iid.tracking_noise(), rng)
    assert abs(noisy["expr"].std() - 0.3) < 0.01 and abs(noisy["expr"].mean()) < 0.01
    assert abs(_autocorrelation(noisy["expr"], 1)) < 0.03
    assert abs(noisy["jaw_pose"].std() - 0.02) < 0.001
    assert abs(noisy["translation"].std() - 0.002) < 0.0001


def test_one_bias_per_capture_shared_by_its_sequences(tmp_path):
    settings = CaptureSettings(views=2, timesteps=48, size=32, supersample=1, expr_noise=0.0, expr_bias=0.5,
                               pose_noise=0.0, pose_bias=0.0, translation_noise=0.0, translation_bias=0.0)
    root = make_capture(tmp_path / "biased", settings, progress=False)
    errors = np.stack([load_npz(root / "flame_param" / f"{t:05d}.npz")["expr"].ravel()
                       - load_npz(root / "flame_param_gt" / f"{t:05d}.npz")["expr"].ravel() for t in range(48)])
    np.testing.assert_allclose(errors, np.broadcast_to(errors[0], errors.shape), atol=1e-5)  # every timestep, every sequence
    assert 0.2 < errors[0].std() < 0.8
    rotation = load_npz(root / "flame_param" / "00007.npz")["rotation"] - load_npz(root / "flame_param_gt" / "00007.npz")["rotation"]
    np.testing.assert_allclose(rotation, 0.0, atol=1e-7)


def test_sequences_exercise_every_component_smoothly():
    sequences = make_sequences(150, 4, 11, [9, 10], seed=0)
    assert [s.name for s in sequences] == ["EXP-1", "EXP-2", "SPEECH", "FREE", "VAL"]
    assert sum(s.length for s in sequences[:4]) == 150 and sequences[4].length == 8  # VAL: 5 % on top
    expression_runs = np.concatenate([sequences[0].params["expr"], sequences[1].params["expr"]])
    assert np.all(np.abs(expression_runs).max(0) > 0.5)  # every component exercised
    for s in sequences:
        steps = np.abs(np.diff(s.params["expr"], axis=0)).max()
        assert steps < 0.9, (s.name, steps)  # smooth in time
    jaw = np.concatenate([s.params["jaw_pose"][:, 0] for s in sequences])
    eyes = np.concatenate([s.params["eyes_pose"] for s in sequences])
    assert jaw.max() > 0.15 and np.abs(eyes).max() > 0.1


def test_same_settings_same_capture(tiny_capture, tmp_path):
    again = make_capture(tmp_path / "again", TINY, progress=False)

    def digest(root):
        files = sorted(p for p in root.rglob("*") if p.is_file())
        return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}

    assert digest(tiny_capture) == digest(again)


def test_camera_noise_perturbs_only_the_written_cameras(tmp_path):
    noisy = make_capture(tmp_path / "noisy", CaptureSettings(views=3, timesteps=16, size=32, supersample=1, camera_noise=1.0), progress=False)
    truth = json.loads((noisy / "cameras_gt.json").read_text())
    capture = Capture.open(noisy)
    frame = capture.frames("train")[0]
    written = np.array(json.loads((noisy / "transforms_train.json").read_text())["frames"][0]["transform_matrix"])
    true = np.array(truth[frame.camera_id]["transform_matrix"])
    angle = np.degrees(np.arccos(np.clip((np.trace(written[:3, :3].T @ true[:3, :3]) - 1) / 2, -1, 1)))
    assert 0.05 < angle < 5.0


def test_camera_centre_noise_sets_the_centres_error_alone():
    """The turn is drawn as before (same angles); only the centre's error follows the setting."""
    head = np.random.default_rng(0).normal(scale=0.08, size=(100, 3))
    true = camera_dome(6, 64, head, np.random.default_rng(1))[0]

    def reported(centre_mm, seed=3):
        rng = np.random.default_rng(seed)
        return [perturb_camera(c, 1.0, rng, centre_mm) for c in true]

    held, default, wide = reported(0.0), reported(None), reported(20.0)
    for truth, h, d, w in zip(true, held, default, wide):
        assert np.allclose(h.center, truth.center, atol=1e-9)
        assert np.allclose(h.w2c[:3, :3], d.w2c[:3, :3]) and np.allclose(h.w2c[:3, :3], w.w2c[:3, :3])
        assert np.allclose(w.center - truth.center, 4.0 * (d.center - truth.center))  # 20 mm against 5 mm
    assert 0.002 < np.mean([np.linalg.norm(d.center - t.center) for d, t in zip(default, true)]) < 0.02
    assert perturb_camera(true[0], 0.0, np.random.default_rng(0)) is true[0]


def test_bad_settings_are_refused(tmp_path):
    with pytest.raises(InputError, match="views"):
        make_capture(tmp_path / "x", CaptureSettings(views=1), progress=False)
    with pytest.raises(InputError, match="expr_noise"):
        make_capture(tmp_path / "x", CaptureSettings(expr_noise=-1), progress=False)
    with pytest.raises(InputError, match="camera_centre_noise"):
        make_capture(tmp_path / "x", CaptureSettings(camera_centre_noise=-1.0), progress=False)
    with pytest.raises(InputError, match="pose_correlation"):
        make_capture(tmp_path / "x", CaptureSettings(pose_correlation=-2), progress=False)


def test_make_capture_cli(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "mogaface", "make-capture", tmp_path / "cli", "--views", "3", "--timesteps", "16",
         "--size", "32", "--quiet"],
        capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stderr
    assert "views: 3" in result.stdout and "split test" in result.stdout
    assert (tmp_path / "cli" / "head.pkl").is_file()
    written = json.loads((tmp_path / "cli" / "capture_info.json").read_text())["settings"]
    assert written["expr_correlation"] == CaptureSettings().expr_correlation > 0 and written["pose_bias"] > 0


def test_make_capture_cli_noise_options(tmp_path):
    from mogaface.core.cli import main

    assert main(["make-capture", str(tmp_path / "iid"), "--views", "2", "--timesteps", "16", "--size", "32",
                 "--iid-noise", "--pose-noise", "0.02", "--quiet"]) == 0
    written = json.loads((tmp_path / "iid" / "capture_info.json").read_text())["settings"]
    assert written["expr_noise"] == 0.5 and written["pose_noise"] == 0.02 and written["translation_noise"] == 0.001
    assert all(written[f"{g}_{k}"] == 0 for g in ("expr", "pose", "translation") for k in ("correlation", "bias"))
    assert main(["make-capture", str(tmp_path / "slow"), "--views", "2", "--timesteps", "16", "--size", "32",
                 "--expr-correlation", "8", "--translation-bias", "0.002", "--quiet"]) == 0
    written = json.loads((tmp_path / "slow" / "capture_info.json").read_text())["settings"]
    assert written["expr_correlation"] == 8 and written["translation_bias"] == 0.002


def test_the_validation_sequence_is_a_script_of_its_own_and_leaves_the_others_as_they_were():
    from mogaface.core.data import sequences as module

    five = make_sequences(150, 4, 11, [9, 10], seed=0)
    free, val = five[3].params["expr"], five[4].params["expr"]
    active = lambda expr: (np.abs(expr) > 0.1).mean()  # noqa: E731  share of components in use
    assert active(val) < 0.6 < active(free)  # a few components at a time, not all wandering together
    assert np.abs(val).max() > 0.5 and np.abs(five[4].params["jaw_pose"]).max() > 0
    # the draws of the other sequences come first: without VAL they are the same
    original = module.validation_sequence
    try:
        module.validation_sequence = lambda rng, length, n_expr: original(np.random.default_rng(99), length, n_expr)
        again = make_sequences(150, 4, 11, [9, 10], seed=0)
    finally:
        module.validation_sequence = original
    for a, b in zip(five[:4], again[:4]):
        for key in a.params:
            np.testing.assert_array_equal(a.params[key], b.params[key])
    assert not np.array_equal(again[4].params["expr"], val)
    assert module.validation_timesteps(16) == 2 and module.validation_timesteps(150) == 8


def test_a_non_square_capture_has_its_size_and_a_square_one_is_unchanged(tmp_path):
    """NeRSemble's frames are 802×550: ``height`` makes such a capture, rendered at that size; a
    square capture with ``height`` given draws the same rig and images as one without it."""
    import dataclasses

    wide = dataclasses.replace(TINY, timesteps=16, views=3, size=64, height=44, supersample=1)
    root = make_capture(tmp_path / "wide", wide, progress=False)
    capture = Capture.open(root)
    frame = capture.frames("train")[0]
    camera = capture.camera(frame)
    rgb, mask = capture.load_image(frame)
    assert rgb.shape[:2] == mask.shape == (44, 64) and (camera.width, camera.height) == (64, 44)
    assert abs(camera.cx - 32) < 4 and abs(camera.cy - 22) < 4
    assert validate_capture(root).views == 3
    same = dataclasses.replace(wide, height=None)
    square = make_capture(tmp_path / "square", same, progress=False)
    given = make_capture(tmp_path / "given", dataclasses.replace(same, height=64), progress=False)
    for path in sorted((square / "images").rglob("*.png"))[:6]:
        assert path.read_bytes() == (given / path.relative_to(square)).read_bytes()
    assert (square / "transforms_train.json").read_bytes() == (given / "transforms_train.json").read_bytes()
    with pytest.raises(InputError, match="height"):
        dataclasses.replace(wide, height=8).check()
