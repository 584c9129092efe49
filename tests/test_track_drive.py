"""`drive`: a performance clip tracked with an avatar's shape held fixed, retimed, put on the
avatar's rest pose, thinned within a tolerance."""

import json

import numpy as np
import pytest

from mogaface.core.errors import InputError
from mogaface.core.io.npz import load_npz, save_npz
from mogaface.core.workflows.drive import Identity, drive_clip, put_on_rest, retime, thin_channel, thinned


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


def test_the_commands_write_progress_events_and_drive_a_tracked_capture(handheld, tmp_path, capsys):
    """``track`` with ``--events``; then ``drive`` of the clip onto that capture: its shape held fixed
    (not fitted again), its first pose kept, retimed to 15 fps."""
    from mogaface.core.cli import main

    clip, capture, events = handheld / "footage" / "clip.mp4", tmp_path / "capture", tmp_path / "events.jsonl"
    assert main(["track", str(clip), "--out", str(capture), "--size", "112", "--fit-steps", "3", "--quiet",
                 "--photometric-steps", "20", "--photometric-stride", "3", "--events", str(events)]) == 0
    tracking = json.loads((capture / "tracking.json").read_text())
    assert (tracking["photometric_steps"], tracking["photometric_stride"], tracking["photometric_fine_steps"],
            tracking["photometric_shading"]) == (20, 3, 5, True)
    lines = [json.loads(line) for line in events.read_text().splitlines()]
    assert {e["stage"] for e in lines if e["event"] == "iter"} == {"detect", "fit", "write"}
    assert all(e["eta_s"] is not None and e["eta_s"] >= 0 for e in lines if e["event"] == "iter")
    assert lines[-1]["event"] == "done" and lines[-1]["frames"] == 12
    out = tmp_path / "performance"
    assert main(["drive", str(clip), "--avatar", str(capture), "--out", str(out), "--size", "112", "--fit-steps",
                 "3", "--photometric-steps", "20", "--photometric-stride", "2", "--to-fps", "15", "--keep-head-still",
                 "--tolerance", "0.001", "--quiet", "--capture", str(tmp_path / "tracked")]) == 0
    assert "drove 6 frames at 15 fps" in capsys.readouterr().out
    assert json.loads((tmp_path / "tracked" / "tracking.json").read_text())["photometric_stride"] == 2
    report = json.loads((out / "drive.json").read_text())
    assert report["frames"] == 6 and report["clip_fps"] == 30.0 and report["keys"] < report["keys_dense"]
    rest = load_npz(capture / "flame_param" / "00000.npz")
    held = load_npz(tmp_path / "tracked" / "flame_param" / "00000.npz")["shape"]
    np.testing.assert_allclose(held.reshape(-1), rest["shape"].reshape(-1), atol=1e-6)  # held, not fitted
    for t in (0, 5):
        frame = load_npz(out / f"{t:05d}.npz")
        for name in ("shape", "rotation", "translation"):  # the capture's identity, held at its first pose
            np.testing.assert_allclose(frame[name].reshape(-1), rest[name].reshape(-1), atol=1e-6)
    expr = np.stack([load_npz(out / f"{t:05d}.npz")["expr"].reshape(-1) for t in range(6)])
    assert not np.allclose(expr[0], expr[-1])  # the face moves
    assert main(["drive", str(clip), "--avatar", str(capture), "--out", str(tmp_path / "x"), "--tolerance", "-1"]) == 2
    with pytest.raises(InputError, match="not empty"):
        drive_clip(clip, Identity.of(capture), out)
    save_npz(tmp_path / "identity.npz", {"shape": np.zeros(3), "rotation": np.zeros(2)})
    with pytest.raises(InputError, match="head model"):
        Identity.of(tmp_path / "identity.npz")
    with pytest.raises(InputError, match="rotation"):
        Identity.of(tmp_path / "identity.npz", capture / "head.pkl")
