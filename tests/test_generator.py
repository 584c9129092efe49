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
from mogaface.core.data.generator import CaptureSettings, camera_dome, make_capture
from mogaface.core.data.sequences import TrackingNoise, add_tracking_noise, make_sequences
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
    assert summary.views == 4 and summary.timesteps == 16
    assert set(summary.sequences) == {"EXP-1", "EXP-2", "SPEECH", "FREE"}
    capture = Capture.open(tiny_capture)
    val_cameras = {f.camera_id for f in capture.frames("val")}
    assert val_cameras == {info["val_camera"]}
    assert {f.sequence for f in capture.frames("test")} == {"FREE"}
    assert len({f.camera_id for f in capture.frames("test")}) == 4
    train = capture.frames("train")
    assert info["val_camera"] not in {f.camera_id for f in train}
    assert "FREE" not in {f.sequence for f in train}
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
    expr_std = np.concatenate(diffs["expr"]).std()
    assert abs(expr_std - settings["expr_noise"]) < 0.15 * settings["expr_noise"]
    assert np.concatenate(diffs["jaw_pose"]).std() < 3 * settings["pose_noise"]


def test_noise_statistics_over_many_timesteps():
    rng = np.random.default_rng(0)
    params = {k: np.zeros((4000, n), np.float32) for k, n in
              [("shape", 5), ("expr", 10), ("rotation", 3), ("neck_pose", 3), ("jaw_pose", 3), ("eyes_pose", 6), ("translation", 3)]}
    noisy = add_tracking_noise(params, TrackingNoise(expr=0.3, pose=0.02), rng)
    assert abs(noisy["expr"].std() - 0.3) < 0.01 and abs(noisy["expr"].mean()) < 0.01
    assert abs(noisy["jaw_pose"].std() - 0.02) < 0.001
    assert abs(noisy["translation"].std() - 0.002) < 0.0001
    np.testing.assert_array_equal(noisy["shape"], 0.0)


def test_sequences_exercise_every_component_smoothly():
    sequences = make_sequences(150, 4, 11, [9, 10], seed=0)
    assert [s.name for s in sequences] == ["EXP-1", "EXP-2", "SPEECH", "FREE"]
    assert sum(s.length for s in sequences) == 150
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


def test_bad_settings_are_refused(tmp_path):
    with pytest.raises(InputError, match="views"):
        make_capture(tmp_path / "x", CaptureSettings(views=1), progress=False)
    with pytest.raises(InputError, match="expr_noise"):
        make_capture(tmp_path / "x", CaptureSettings(expr_noise=-1), progress=False)


def test_make_capture_cli(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "mogaface", "make-capture", tmp_path / "cli", "--views", "3", "--timesteps", "16",
         "--size", "32", "--quiet"],
        capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stderr
    assert "views: 3" in result.stdout and "split test" in result.stdout
    assert (tmp_path / "cli" / "head.pkl").is_file()
