"""The start of the image-assisted sources on frames a run never saw: the tracked parameters moved
by the run's mean fine-tuning offset. The offset is the mean over the training timesteps, the
run's own parameters are kept where it has them, a run that kept the tracking (Freeze) moves
nothing, and a tracker's constant error is taken out of unseen frames in the avatar's gauge."""

import shutil

import numpy as np
import pytest
from test_evaluate_fixtures import make_fake_run, tiny_capture

from mogaface.core.data import layout
from mogaface.core.data.capture import Capture
from mogaface.core.evaluate.expression_error import tracking_errors, truth_folder
from mogaface.core.evaluate.sources.tracked import AlignedTrackedParams, TrackedParams, mean_finetuning_offset
from mogaface.core.io.npz import save_npz
from mogaface.core.run.folder import MOTION_KEYS, RunFolder, load_flame_file

BIAS = {"expr": 1.0, "rotation": 0.02, "translation": 0.003}  # a tracker's constant error, larger than its drift


def _write(path, params):
    save_npz(path, layout.batched_flame_params(params))


@pytest.fixture(scope="module")
def biased(tmp_path_factory):
    """The tiny capture whose tracking carries a constant error on top of its own, and a run that
    fine-tuned its training timesteps 60 % of the way from that tracking to the truth."""
    root = tmp_path_factory.mktemp("biased") / "capture"
    shutil.copytree(tiny_capture(tmp_path_factory), root)
    capture = Capture.open(root)
    truth = {t: load_flame_file(truth_folder(capture) / f"{t:05d}.npz") for t in capture.timesteps}
    for t in capture.timesteps:
        path = root / layout.flame_param_path(t)
        params = layout.normalize_flame_params(dict(np.load(path)), path)
        for key, bias in BIAS.items():
            params[key] = params[key] + np.float32(bias)
        _write(path, params)
    capture = Capture.open(root)
    run_root = make_fake_run(tmp_path_factory.mktemp("biased_run") / "run", root)
    run = RunFolder(run_root)
    for t in run.trained_timesteps:
        params, tracked = run.flame_params(t), capture.flame_params(t)
        for key in MOTION_KEYS:
            params[key] = (tracked[key] + 0.6 * (truth[t][key] - tracked[key])).astype(np.float32)
        _write(run.flame_param_dir / f"{t:05d}.npz", params)
    return capture, RunFolder(run_root), truth


def test_the_offset_is_the_mean_move_of_the_training_timesteps(biased):
    capture, run, truth = biased
    offset = mean_finetuning_offset(run, capture)
    trained = run.trained_timesteps
    for key in ("expr", "rotation", "translation"):  # fine-tuning moved 60 % of the tracker's error
        error = np.mean([capture.flame_params(t)[key] - truth[t][key] for t in trained], axis=0)
        np.testing.assert_allclose(offset[key], -0.6 * error, rtol=1e-4, atol=1e-6)
    source = AlignedTrackedParams(capture, run)
    tracked = TrackedParams(capture, run)
    unseen = [t for t in capture.timesteps if t not in trained]
    assert unseen
    for t in unseen:
        moved, start = source.params_for(t), tracked.params_for(t)
        np.testing.assert_allclose(moved["expr"], start["expr"] + offset["expr"], rtol=1e-6)
        np.testing.assert_array_equal(moved["shape"], start["shape"])  # the identity is the run's, not moved
    for t in trained:  # the run's own parameters where it has them
        np.testing.assert_array_equal(source.params_for(t)["expr"], run.flame_params(t)["expr"])


def test_a_tracker_constant_error_leaves_unseen_frames_in_the_avatars_gauge(biased):
    capture, run, truth = biased
    trained = run.trained_timesteps
    gauge = {k: np.mean([run.flame_params(t)[k] - truth[t][k] for t in trained], axis=0) for k in MOTION_KEYS}
    mean_error = {k: np.mean([capture.flame_params(t)[k] - truth[t][k] for t in trained], axis=0) for k in MOTION_KEYS}
    source = AlignedTrackedParams(capture, run)
    for t in [t for t in capture.timesteps if t not in trained]:  # what is left: the error's change since training
        for key in ("expr", "rotation", "translation"):
            left = source.params_for(t)[key] - (truth[t][key] + gauge[key])
            np.testing.assert_allclose(left, capture.flame_params(t)[key] - truth[t][key] - mean_error[key],
                                       rtol=1e-4, atol=1e-5)
    errors = tracking_errors(run, capture, {"tracked": TrackedParams(capture, run).params_for,
                                            "aligned": source.params_for})
    tracked, aligned = errors["tracked"]["unseen"], errors["aligned"]["unseen"]
    assert aligned["vertex_mm_gauge"] < 0.8 * tracked["vertex_mm_gauge"]
    assert aligned["expr_vertex_mm_gauge"] < 0.8 * tracked["expr_vertex_mm_gauge"]
    assert errors["aligned"]["training"] == errors["tracked"]["training"]  # the run's own, both


def test_a_run_that_kept_the_tracking_moves_nothing(tmp_path_factory):
    root = tiny_capture(tmp_path_factory)
    run = RunFolder(make_fake_run(tmp_path_factory.mktemp("freeze") / "run", root))
    capture = Capture.open(root)
    for t in run.trained_timesteps:  # Freeze: the tracked motion, the identity training refined
        params = {**capture.flame_params(t), "shape": run.flame_params(t)["shape"]}
        _write(run.flame_param_dir / f"{t:05d}.npz", params)
    assert mean_finetuning_offset(run, capture) == {}
    unseen = [t for t in capture.timesteps if t not in run.trained_timesteps]
    moved = AlignedTrackedParams(capture, run).params_for(unseen[0])
    start = TrackedParams(capture, run).params_for(unseen[0])
    for key in MOTION_KEYS:
        np.testing.assert_array_equal(moved[key], start[key])


def test_a_parameter_whose_size_differs_from_the_trackers_is_left_alone(tmp_path_factory):
    root = tiny_capture(tmp_path_factory)
    run = RunFolder(make_fake_run(tmp_path_factory.mktemp("sizes") / "run", root))
    for t in run.trained_timesteps:  # a run with fewer expression coefficients than the tracker's files
        params = run.flame_params(t)
        params["expr"] = params["expr"][:-1] + 0.1
        params["jaw_pose"] = params["jaw_pose"] + 0.01
        _write(run.flame_param_dir / f"{t:05d}.npz", params)
    offset = mean_finetuning_offset(run, Capture.open(root))
    assert "expr" not in offset
    np.testing.assert_allclose(offset["jaw_pose"], 0.01, rtol=1e-4)
