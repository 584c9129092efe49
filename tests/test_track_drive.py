"""`drive`: a performance clip tracked with an avatar's shape held fixed, retimed, put on the
avatar's rest pose, thinned within a tolerance."""

import json

import numpy as np
import pytest

from mogaface.core.errors import InputError
from mogaface.core.io.npz import load_npz, save_npz
from mogaface.core.scene.tracking import thin_channel, thinned
from mogaface.core.track.drive import DriveSettings, Identity, drive_clip, put_on_rest, retime


def test_retiming_keeps_the_span_and_samples_the_motion_linearly():
    ramp = np.stack([np.arange(31) / 30.0, np.sin(np.arange(31) / 30.0)], 1)  # one second at 30 fps
    out = retime(ramp, 30.0, 24.0)
    assert out.shape == (25, 2)  # one second at 24 fps, both ends included
    np.testing.assert_allclose(out[:, 0], np.arange(25) / 24.0, atol=1e-12)  # a line stays the line
    np.testing.assert_allclose(out[:, 1], np.sin(np.arange(25) / 24.0), atol=2e-4)
    assert retime(ramp, 30.0, 30.0).shape == ramp.shape
    assert retime(ramp, 30.0, 60.0).shape == (61, 2)
    with pytest.raises(InputError, match="fps"):
        retime(ramp, 0.0, 24.0)


def test_thinning_keeps_every_value_within_the_tolerance_and_drops_the_rest():
    t = np.linspace(0, 2, 200)
    values = np.stack([np.sin(3 * t), np.where(t < 1, 0.0, 0.5), 0.1 * t], 1)
    for tolerance in (0.001, 0.02):
        played, keys = thinned(values, tolerance)
        assert np.abs(played - values).max() <= tolerance + 1e-12
        assert keys < values.size // 3
    assert len(thin_channel(values[:, 2], 1e-6)) == 2  # a straight line: its two ends
    assert len(thin_channel(values[:, 1], 1e-3)) == 4  # a step: the ends and its two corners
    np.testing.assert_array_equal(thin_channel(values[:, 0], 0.0), np.arange(200))  # no tolerance: every key


def test_the_head_moves_relative_to_the_performers_mean_pose_onto_the_avatars_rest():
    rng = np.random.default_rng(0)
    frames = 8
    params = {"expr": rng.normal(size=(frames, 4)), "jaw_pose": rng.normal(0, 0.1, (frames, 3)),
              "rotation": np.array([0.0, 0.3, 0.0]) + rng.normal(0, 0.05, (frames, 3)),
              "neck_pose": np.zeros((frames, 3)), "translation": np.array([0.02, 0.0, 0.1]) + rng.normal(0, 0.01, (frames, 3))}
    rest = {"rotation": np.array([0.1, 0.0, 0.0]), "neck_pose": np.zeros(3), "translation": np.array([0.0, 0.01, 0.0])}
    out = put_on_rest(params, rest)
    np.testing.assert_allclose(out["translation"].mean(0), rest["translation"], atol=1e-12)
    np.testing.assert_allclose(out["translation"] - out["translation"][0],
                               params["translation"] - params["translation"][0], atol=1e-12)
    from scipy.spatial.transform import Rotation

    mean = Rotation.from_rotvec(out["rotation"]).mean().as_rotvec()
    np.testing.assert_allclose(mean, rest["rotation"], atol=1e-6)
    np.testing.assert_array_equal(out["expr"], params["expr"])  # the face is carried as it is
    still = put_on_rest(params, rest, keep_head_still=True)
    for name in ("rotation", "neck_pose", "translation"):
        np.testing.assert_array_equal(still[name], np.tile(rest[name], (frames, 1)))
    np.testing.assert_array_equal(still["jaw_pose"], params["jaw_pose"])


def test_a_clip_drives_an_identity_with_its_shape_held_fixed(handheld, procedural_head_pkl, tmp_path):
    shape = np.zeros(300)
    shape[:5] = [1.5, -1.0, 0.5, 0.8, -0.3]
    rest = np.array([0.0, 0.2, 0.0])
    save_npz(tmp_path / "identity.npz", {"shape": shape, "rotation": rest})
    identity = Identity.of(tmp_path / "identity.npz", procedural_head_pkl)
    out = tmp_path / "performance"
    result = drive_clip(handheld / "footage" / "clip.mp4", identity, out,
                        DriveSettings(fps=20.0, keep_head_still=True, tolerance=0.001, fit_steps=5, size=None),
                        capture=tmp_path / "tracked")
    assert result["frames"] == 8 and result["fps"] == 20.0 and result["clip_fps"] == 30.0  # 12 frames at 30 fps
    report = json.loads((out / "drive.json").read_text())
    assert report["frames"] == 8 and report["keys"] <= report["keys_dense"]
    files = sorted(out.glob("*.npz"))
    assert [f.stem for f in files] == [f"{t:05d}" for t in range(8)]
    tracked = load_npz(tmp_path / "tracked" / "flame_param" / "00000.npz")
    n_shape = tracked["shape"].reshape(-1).shape[0]
    np.testing.assert_allclose(tracked["shape"].reshape(-1), shape[:n_shape], atol=1e-6)  # held, not fitted
    frame = load_npz(files[3])
    np.testing.assert_allclose(frame["shape"].reshape(-1), shape, atol=1e-6)
    np.testing.assert_allclose(frame["rotation"].reshape(-1), rest, atol=1e-6)  # kept still on the rest pose
    expr = np.stack([load_npz(f)["expr"].reshape(-1) for f in files])
    assert np.abs(expr).max() > 0 and not np.allclose(expr[0], expr[-1])  # the face moves
    with pytest.raises(InputError, match="not empty"):
        drive_clip(handheld / "footage" / "clip.mp4", identity, out)
    with pytest.raises(InputError, match="head model"):
        Identity.of(tmp_path / "identity.npz")


def test_the_commands_write_progress_events_and_drive_a_tracked_capture(handheld, tmp_path, capsys):
    from mogaface.core.cli import main

    clip, capture, events = handheld / "footage" / "clip.mp4", tmp_path / "capture", tmp_path / "events.jsonl"
    assert main(["track", str(clip), "--out", str(capture), "--size", "112", "--fit-steps", "3", "--quiet",
                 "--events", str(events)]) == 0
    lines = [json.loads(line) for line in events.read_text().splitlines()]
    assert {e["stage"] for e in lines if e["event"] == "iter"} == {"detect", "fit", "write"}
    assert all(e["eta_s"] is not None and e["eta_s"] >= 0 for e in lines if e["event"] == "iter")
    assert lines[-1]["event"] == "done" and lines[-1]["frames"] == 12
    out = tmp_path / "performance"
    assert main(["drive", str(clip), "--avatar", str(capture), "--out", str(out), "--size", "112", "--fit-steps",
                 "3", "--to-fps", "15", "--keep-head-still", "--quiet"]) == 0
    assert "drove 6 frames at 15 fps" in capsys.readouterr().out
    rest = load_npz(capture / "flame_param" / "00000.npz")
    for t in (0, 5):
        frame = load_npz(out / f"{t:05d}.npz")
        for name in ("shape", "rotation", "translation"):  # the capture's identity, held at its first pose
            np.testing.assert_allclose(frame[name].reshape(-1), rest[name].reshape(-1), atol=1e-6)
    assert main(["drive", str(clip), "--avatar", str(capture), "--out", str(tmp_path / "x"), "--tolerance", "-1"]) == 2
