"""The held-out camera aligned to the avatar: a moved camera is brought back, a right one stays,
and the protocol scores only frames its alignment never looked at."""

import json

import numpy as np
import pytest
import torch
from test_evaluate_fixtures import fake_run, render_np, tiny_capture, watch_target_images

from mogaface.core.cli import main
from mogaface.core.data.capture import Capture
from mogaface.core.data.generator import perturb_camera
from mogaface.core.errors import InputError
from mogaface.core.evaluate import protocols
from mogaface.core.evaluate.camera_alignment import align_camera, split_frames
from mogaface.core.evaluate.camera_error import pose_error
from mogaface.core.evaluate.evaluation import evaluate_run
from mogaface.core.evaluate.protocols import TrackedParams, protocol_frames
from mogaface.core.run.folder import RunFolder


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The fake run's avatar, three of its frames seen by the held-out camera at twice the size."""
    capture = Capture.open(tiny_capture(tmp_path_factory))
    run = RunFolder(fake_run(tmp_path_factory))
    avatar = run.load_avatar()
    frames = protocol_frames(capture, "novel_view", max_frames=3)
    camera = capture.camera(frames[0]).scaled(2)
    params = [TrackedParams(capture, run).params_for(f, f.camera_id) for f in frames]
    views = [(p, render_np(avatar, p, camera)[0]) for p in params]
    return avatar, camera, views


def head_pixels(avatar, params, camera, truth) -> float:
    from mogaface.core.avatar.avatar import flame_params_to_torch

    with torch.no_grad():
        vertices = avatar.posed_vertices(flame_params_to_torch(params)).double().numpy()
    return float(np.mean(np.linalg.norm(camera.project(vertices)[0] - truth.project(vertices)[0], axis=1)))


def test_a_moved_camera_is_brought_back_to_the_avatar(scene):
    avatar, truth, views = scene
    start = perturb_camera(truth, 1.0, np.random.default_rng(3))
    before = head_pixels(avatar, views[0][0], start, truth)
    aligned, info = align_camera(avatar, start, views, (1.0, 1.0, 1.0))
    after = head_pixels(avatar, views[0][0], aligned, truth)
    assert before > 2.0, before  # the start is visibly off
    assert info["kept"] and info["fit_l1_after"] < 0.5 * info["fit_l1_before"]
    assert after < 0.3 * before, (before, after)
    assert pose_error(aligned, truth)[0] < 0.5 * pose_error(start, truth)[0]
    assert info["fit_frames"] == 3 and info["rotation_deg"] > 0.3


def test_a_right_camera_stays_where_it_is(scene):
    avatar, truth, views = scene
    aligned, info = align_camera(avatar, truth, views, (1.0, 1.0, 1.0))
    # Nothing to gain: the fit wanders by a hair, does not lower the error, and is not kept.
    assert not info["kept"] and info["fit_l1_after"] >= info["fit_l1_before"]
    assert np.array_equal(aligned.w2c, truth.w2c) and info["rotation_deg"] == info["shift_mm"] == 0.0
    with pytest.raises(ValueError, match="at least one view"):
        align_camera(avatar, truth, [], (1.0, 1.0, 1.0))


def test_split_alternates_within_each_camera(tmp_path_factory):
    capture = Capture.open(tiny_capture(tmp_path_factory))
    frames = capture.frames("train")
    fit, scored = split_frames(frames)
    assert sorted(map(id, fit + scored)) == sorted(map(id, frames))
    assert not {(f.camera_id, f.timestep_index) for f in fit} & {(f.camera_id, f.timestep_index) for f in scored}
    for camera_id in {f.camera_id for f in frames}:
        steps = sorted(f.timestep_index for f in frames if f.camera_id == camera_id)
        assert [f.timestep_index for f in fit if f.camera_id == camera_id] == steps[0::2]
        assert [f.timestep_index for f in scored if f.camera_id == camera_id] == steps[1::2]


def test_the_aligned_protocol_scores_only_what_its_alignment_never_saw(tmp_path_factory, tmp_path, monkeypatch):
    root = fake_run(tmp_path_factory)
    loaded = watch_target_images(monkeypatch)
    result = evaluate_run(root, ["novel_view", "novel_view_aligned"], 6, lpips=False, out_dir=tmp_path)
    capture = Capture.open(tiny_capture(tmp_path_factory))
    frames = protocol_frames(capture, "novel_view", max_frames=6)
    fit, scored = split_frames(frames)
    aligned = result["protocols"]["novel_view_aligned"]
    assert aligned["frames"] == len(scored) == 3
    assert [r["timestep"] for r in aligned["per_frame"]] == [f.timestep_index for f in scored]
    seen = loaded[len(frames):len(frames) + len(fit)]  # after novel_view's six: the alignment's views
    assert seen == [(f.camera_id, f.timestep_index) for f in fit]
    assert not set(seen) & {(f.camera_id, f.timestep_index) for f in scored}
    info = aligned["alignment"]["cam01"]
    assert info["fit_frames"] == 3 and info["kept"] == (info["fit_l1_after"] < info["fit_l1_before"])
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert on_disk["protocols"]["novel_view_aligned"]["alignment"]["cam01"]["kept"] == info["kept"]
    assert "| novel view aligned | 3 |" in (tmp_path / "metrics.md").read_text()
    with pytest.raises(InputError, match="two or more frames"):
        evaluate_run(root, ["novel_view_aligned"], 1, lpips=False, out_dir=tmp_path)


def test_eval_cli_takes_the_aligned_protocol_only_when_asked(tmp_path_factory, tmp_path, capsys):
    root = fake_run(tmp_path_factory)
    assert main(["eval", str(root), "--max-frames", "2", "--no-lpips", "--quiet", "--out", str(tmp_path)]) == 0
    assert "novel_view_aligned" not in json.loads((tmp_path / "metrics.json").read_text())["protocols"]
    assert main(["eval", str(root), "--protocols", "novel_view_aligned", "--max-frames", "4", "--no-lpips",
                 "--quiet", "--out", str(tmp_path)]) == 0
    assert json.loads((tmp_path / "metrics.json").read_text())["protocols"]["novel_view_aligned"]["frames"] == 2
    assert "novel view aligned" in capsys.readouterr().out


def test_a_held_out_camera_that_moves_between_frames_is_refused(tmp_path_factory, monkeypatch):
    capture = Capture.open(tiny_capture(tmp_path_factory))
    run = RunFolder(fake_run(tmp_path_factory))
    frames = protocol_frames(capture, "novel_view", max_frames=4)
    moved = perturb_camera(capture.camera(frames[-1]), 1.0, np.random.default_rng(0))

    class Moving:
        def __init__(self, capture):
            self.capture = capture

        def __call__(self, frame):
            return moved if frame is frames[-1] else self.capture.camera(frame)

    monkeypatch.setattr(protocols, "ScoringCameras", Moving)
    with pytest.raises(InputError, match="moves between frames"):
        protocols.novel_view_aligned(run.load_avatar(), capture, TrackedParams(capture, run), run.background, frames)
