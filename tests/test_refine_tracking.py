"""Improving a capture's tracking with a run's refiner (``refine-tracking``): every timestep is
written in the capture's own flame_param layout, as plain numpy and the Blender reader see it,
with the values the evaluation's refined source computes (and, with fitting steps, its fitting
from there on the timesteps training did not fit, which lowers the image error in their views);
a run without a refiner gets one; a stopped job and a folder it did not write are left as they
were; on a synthetic capture the record says how far the start and the result are from the
truth."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from test_evaluate_fixtures import fake_run, tiny_capture

from mogaface.core.data.capture import Capture
from mogaface.core.errors import InputError
from mogaface.core.evaluate.sources.refined import RefinedParams, run_refiner
from mogaface.core.evaluate.sources.tracked import AlignedTrackedParams, TrackedParams
from mogaface.core.for_blender.tracking import read_tracking
from mogaface.core.for_blender.worker import RefineTrackingWorker
from mogaface.core.refiner.training import RefinerSettings, frozen_avatar, train_refiner
from mogaface.core.run.cameras import InputCameras
from mogaface.core.run.folder import RunFolder
from mogaface.core.workflows.refine_tracking import RECORD_FILE, refine_tracking

TINY = dict(starts=2, offsets_per_start=2, gap_timesteps=2, threads=1,
            spec={"grid": 4, "render_limit": 64, "prior": 1.0, "gap_rank": 1})


@pytest.fixture(scope="module")
def run_root(tmp_path_factory):
    """The fake run with a tiny refiner."""
    tiny_capture(tmp_path_factory)
    root = tmp_path_factory.mktemp("tracking") / "run"
    shutil.copytree(fake_run(tmp_path_factory), root)
    train_refiner(root, RefinerSettings(**TINY))
    return root


@pytest.fixture(scope="module")
def refined(run_root, tmp_path_factory):
    """The run's tracking refined once (one pass, 2 views, no fitting), read by several tests: a
    refine of every timestep is the costly part of each."""
    out = tmp_path_factory.mktemp("refined_once") / "refined"
    refine_tracking(run_root, out=out, passes=1, views=2, fit_steps=0, threads=1)
    return out


def test_every_timestep_is_written_in_the_captures_layout_with_the_refined_values(run_root, tmp_path):
    out = tmp_path / "refined"
    events = []
    result = refine_tracking(run_root, out=out, passes=2, views=2, fit_steps=0, threads=1, listeners=[events.append])
    run = RunFolder(run_root)
    capture = Capture.open(run.capture_root)
    assert result["state"] == "done" and result["folders"] == [str(out / "flame_param")]
    files = sorted((out / "flame_param").glob("*.npz"))
    assert [f.name for f in files] == sorted(capture.path(f, "flame_param_path").name
                                             for f in {f.timestep_index: f for f in capture.frames()}.values())
    avatar = frozen_avatar(run_root)
    source = RefinedParams(avatar, capture, AlignedTrackedParams(capture, run), run_refiner(run_root, avatar),
                           run.background, passes=2, max_views=2, cameras=InputCameras.of_run(capture, run_root))
    moved = 0
    for timestep in capture.timesteps:
        with np.load(out / "flame_param" / f"{timestep:05d}.npz") as written:  # plain numpy, VHAP's shapes
            assert written["expr"].shape == (1, capture.flame_params(timestep)["expr"].shape[0])
            assert written["shape"].ndim == 1 and written["translation"].shape == (1, 3)
            expected = source.params_for(timestep)
            for key in ("expr", "rotation", "jaw_pose", "translation"):
                np.testing.assert_allclose(written[key][0], expected[key], rtol=1e-6, atol=1e-7)
            start = AlignedTrackedParams(capture, run).params_for(timestep)
            moved += not np.allclose(written["expr"][0], start["expr"])
    assert moved > 0  # not a copy of the start (the guard keeps only steps the views support)
    tracking = read_tracking(out / "flame_param")  # Blender's Import Tracking reads it, on the tracker's frames
    np.testing.assert_array_equal(tracking.frames, read_tracking(capture.root / "flame_param").frames)
    record = json.loads((out / RECORD_FILE).read_text())
    assert record["passes"] == 2 and record["views"] == 2 and record["timesteps"] == len(capture.timesteps)
    frames = [e for e in events if e["event"] == "iter"]
    assert [e["step"] for e in frames] == list(range(1, len(capture.timesteps) + 1))
    assert events[-1]["event"] == "done" and not list(tmp_path.glob(".refined.*"))


def test_fitting_from_the_refiners_answer_lowers_the_image_error_on_unseen_timesteps(run_root, refined, tmp_path):
    import torch

    from mogaface.core.avatar.avatar import flame_params_to_torch
    from mogaface.core.data.capture_info import capture_info
    from mogaface.core.data.target import target_image
    from mogaface.core.evaluate.sources.fitted import FittedParams
    from mogaface.core.run.folder import load_flame_file

    refine_tracking(run_root, out=tmp_path / "fitted", passes=1, views=2, fit_steps=6, threads=1)
    assert json.loads((tmp_path / "fitted" / RECORD_FILE).read_text())["fit_steps"] == 6
    run = RunFolder(run_root)
    capture = Capture.open(run.capture_root)
    avatar = frozen_avatar(run_root)
    cameras = InputCameras.of_run(capture, run_root)
    recorded = capture_info(capture.root).get("background")

    def image_error(params, timestep):  # mean L1 over every view of the timestep, at full size
        frames = [f for f in capture.frames() if f.timestep_index == timestep]
        with torch.no_grad():
            return np.mean([float((avatar.render(flame_params_to_torch(params), cameras(f), run.background).rgb
                                   - torch.as_tensor(np.array(target_image(capture, f, run.background, recorded))))
                                  .abs().mean()) for f in frames])

    trained = set(run.trained_timesteps)
    unseen = [t for t in capture.timesteps if t not in trained]
    assert trained and len(unseen) >= 4
    record = json.loads((tmp_path / "fitted" / RECORD_FILE).read_text())
    assert record["fitted_timesteps"] == len(unseen)
    before, after = [], []
    for timestep in capture.timesteps:
        name = f"{timestep:05d}.npz"
        answer = load_flame_file(refined / "flame_param" / name)
        fitted = load_flame_file(tmp_path / "fitted" / "flame_param" / name)
        if timestep in trained:  # already fitted by training: the refiner's answer is kept
            np.testing.assert_array_equal(fitted["expr"], answer["expr"])
            continue
        before.append(image_error(answer, timestep))
        after.append(image_error(fitted, timestep))
    assert np.mean(after) < np.mean(before)
    assert sum(a < b for a, b in zip(after, before)) > len(before) / 2
    # what is written is the evaluation's fitting from the refiner's answer, on all the views
    refiner = RefinedParams(avatar, capture, AlignedTrackedParams(capture, run), run_refiner(run_root, avatar),
                            run.background, passes=1, max_views=2, cameras=cameras)
    source = FittedParams(avatar, capture, refiner, 6, run.background, cameras=cameras)
    timestep = unseen[-1]
    expected = source.params_for(timestep)
    np.testing.assert_allclose(load_flame_file(tmp_path / "fitted" / "flame_param" / f"{timestep:05d}.npz")["expr"],
                               expected["expr"], rtol=1e-5, atol=1e-6)
    assert len(source.inputs[-1][1]) == len([f for f in capture.frames() if f.timestep_index == timestep])
    with pytest.raises(InputError, match="fit_steps"):
        refine_tracking(run_root, out=tmp_path / "bad", fit_steps=-1, threads=1)


def test_a_run_that_kept_the_tracking_gets_every_timestep_fitted(run_root, tmp_path, monkeypatch):
    import mogaface.core.evaluate.sources.tracked as tracked_module
    from mogaface.core.run.folder import load_flame_file

    monkeypatch.setattr(tracked_module, "mean_finetuning_offset", lambda run, capture: {})  # as Freeze
    refine_tracking(run_root, out=tmp_path / "fitted", passes=1, views=2, fit_steps=2, threads=1)
    refine_tracking(run_root, out=tmp_path / "refined", passes=1, views=2, fit_steps=0, threads=1)
    capture = Capture.open(RunFolder(run_root).capture_root)
    assert json.loads((tmp_path / "fitted" / RECORD_FILE).read_text())["fitted_timesteps"] == len(capture.timesteps)
    trained = RunFolder(run_root).trained_timesteps
    moved = [not np.allclose(load_flame_file(tmp_path / "fitted" / "flame_param" / f"{t:05d}.npz")["expr"],
                             load_flame_file(tmp_path / "refined" / "flame_param" / f"{t:05d}.npz")["expr"])
             for t in trained]
    assert all(moved)


def test_eval_scores_a_run_with_a_refiner_as_refine_tracking_applies_it(run_root, tmp_path, monkeypatch):
    """The refiner's one pass on every scored frame and no fitting (the defaults): the parameters
    scored are those ``refine-tracking`` writes (less the scored view). With fitting asked for, it
    fits the unseen timesteps only."""
    from mogaface.core.evaluate.evaluation import evaluate_run
    from mogaface.core.evaluate.sources.fitted import FittedParams
    from mogaface.core.evaluate.sources.refined import RefinerInference

    fitted, refined = [], []

    def spy(cls, calls):
        real = cls.params_for
        monkeypatch.setattr(cls, "params_for", lambda self, frame, exclude_view=None:
                            calls.append(frame) or real(self, frame, exclude_view))

    spy(FittedParams, fitted)
    spy(RefinedParams, refined)
    result = evaluate_run(run_root, ["novel_view", "self_reenactment"], 2, lpips=False, out_dir=tmp_path)
    run = RunFolder(run_root)
    trained = set(run.trained_timesteps)
    scored = {name: [(row["timestep"], row["camera"]) for row in result["protocols"][name]["per_frame"]]
              for name in ("novel_view", "self_reenactment")}
    assert scored["novel_view"] and {t for t, _ in scored["novel_view"]} <= trained
    assert scored["self_reenactment"] and not {t for t, _ in scored["self_reenactment"]} & trained
    assert not fitted and "fitting" not in result["inference"]
    assert sorted((f.timestep_index, f.camera_id) for f in refined) == sorted(scored["novel_view"]
                                                                              + scored["self_reenactment"])
    capture = Capture.open(run.capture_root)
    avatar = frozen_avatar(run_root)
    source = RefinerInference(avatar, capture, run, run_refiner(run_root, avatar), fit_steps=10)
    assert [source.fits(t) for t in capture.timesteps] == [t not in trained for t in capture.timesteps]
    assert "then 10 fitting steps" in source.description
    frame = next(f for f in capture.frames() if f.timestep_index not in trained)
    source.params_for(frame, exclude_view=frame.camera_id)
    assert source.inputs[-1][0] == frame.camera_id and frame.camera_id not in source.inputs[-1][1]


def test_a_run_without_a_refiner_gets_one_and_a_stop_keeps_none(run_root, tmp_path):
    bare = tmp_path / "run"
    shutil.copytree(run_root, bare)
    (bare / "refiner.pt").unlink()
    calls = {"n": 0}

    def stop_in_training():
        calls["n"] += 1
        return calls["n"] > 1

    stopped = refine_tracking(bare, refiner_settings=RefinerSettings(**TINY), threads=1, should_stop=stop_in_training)
    assert stopped["state"] == "stopped"
    assert not (bare / "refiner.pt").exists() and not (bare / "refined_tracking").exists()
    assert not list(bare.glob(".refine*"))
    events = []
    result = refine_tracking(bare, refiner_settings=RefinerSettings(**TINY), passes=1, threads=1,
                             listeners=[events.append])
    assert result["state"] == "done" and (bare / "refiner.pt").exists()
    stages = [e.get("stage") for e in events if e["event"] == "iter"]
    assert stages[0] == "refiner offsets" and "refiner gap" in stages and stages[-1] == "frames"
    assert [e["event"] for e in events].count("done") == 1  # the refiner's own start/done stay inside


def test_a_refiner_of_an_earlier_version_is_trained_again(run_root, tmp_path):
    """A run refined before the full-size steps holds a version-2 refiner: ``refine-tracking``
    replaces it rather than failing (Blender's Improve Tracking has no other way to renew it)."""
    import torch

    from mogaface.core.refiner.files import REFINER_VERSION, load_refiner

    old = tmp_path / "run"
    shutil.copytree(run_root, old)
    state = torch.load(old / "refiner.pt", weights_only=True)
    state["version"] = 2
    del state["state"]["curvature"]
    torch.save(state, old / "refiner.pt")
    with pytest.raises(InputError, match="train-refiner"):
        load_refiner(old / "refiner.pt")
    events = []
    result = refine_tracking(old, refiner_settings=RefinerSettings(**TINY), passes=1, views=2, fit_steps=0,
                             threads=1, listeners=[events.append])
    assert result["state"] == "done"
    assert torch.load(old / "refiner.pt", weights_only=True)["version"] == REFINER_VERSION
    assert "refiner curvature" in {e.get("stage") for e in events if e["event"] == "iter"}


def test_a_stopped_job_leaves_the_previous_result_and_a_foreign_folder_is_refused(run_root, refined, tmp_path):
    out = tmp_path / "refined"
    shutil.copytree(refined, out)  # a finished result (one pass, 2 views)
    before = {p.name: p.read_bytes() for p in (out / "flame_param").iterdir()}
    calls = {"n": 0}

    def stop_after_three():
        calls["n"] += 1
        return calls["n"] > 3

    result = refine_tracking(run_root, out=out, passes=3, views=3, threads=1, should_stop=stop_after_three)
    assert result["state"] == "stopped"
    assert {p.name: p.read_bytes() for p in (out / "flame_param").iterdir()} == before
    assert json.loads((out / RECORD_FILE).read_text())["passes"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["refined"]  # no staging left behind
    foreign = tmp_path / "mine"
    (foreign / "flame_param").mkdir(parents=True)
    (foreign / "flame_param" / "00000.npz").write_bytes(b"my own")
    with pytest.raises(InputError, match="not a refined tracking folder"):
        refine_tracking(run_root, out=foreign, threads=1)
    assert (foreign / "flame_param" / "00000.npz").read_bytes() == b"my own"
    with pytest.raises(InputError, match="passes"):
        refine_tracking(run_root, out=out, passes=0)


def test_the_command_and_its_worker(run_root, tmp_path):
    from mogaface.core.for_blender.worker import refine_tracking_command

    out = tmp_path / "refined"
    worker = RefineTrackingWorker(refine_tracking_command(sys.executable, run_root, out=out, passes=1, views=2,
                                                          fit_steps=1, threads=1), run_root).start()
    progress = worker.wait(interval=0.1, timeout=120)
    assert progress.state == "done", (progress.message, worker.stderr_tail())
    assert json.loads((out / RECORD_FILE).read_text())["fit_steps"] == 1
    assert progress.stage == "frames" and progress.step == progress.steps == 18  # 16 + the validation sequence
    assert progress.message == "refined 18 timesteps"
    done = [e for e in worker.events if e["event"] == "done"]
    assert done[0]["folders"] == [str(out / "flame_param")]
    failed = subprocess.run([sys.executable, "-m", "mogaface", "refine-tracking", str(tmp_path / "nothing")],
                            capture_output=True, text=True, timeout=120)
    assert failed.returncode == 2 and "not a run folder" in failed.stderr


def test_errors_against_the_truth_are_zero_for_the_truth_and_its_gauge(run_root, refined):
    from mogaface.core.evaluate.expression_error import frame_errors, tracking_errors, truth_folder
    from mogaface.core.flame.model import FlameModel
    from mogaface.core.run.folder import MOTION_KEYS, load_flame_file

    run = RunFolder(run_root)
    capture = Capture.open(run.capture_root)
    truth = {t: load_flame_file(truth_folder(capture) / f"{t:05d}.npz") for t in capture.timesteps}
    trained = run.trained_timesteps
    offset = {k: np.mean([run.flame_params(t)[k] - truth[t][k] for t in trained], axis=0) for k in MOTION_KEYS}
    start = TrackedParams(capture, run).params_for
    errors = tracking_errors(run, capture, {"truth": truth.__getitem__, "start": start,
                                            "gauge": lambda t: {**truth[t], **{k: truth[t][k] + v
                                                                               for k, v in offset.items()}}})
    assert errors["truth"]["unseen"]["vertex_mm"] == 0 and errors["truth"]["training"]["expr_vertex_mm"] == 0
    assert errors["gauge"]["unseen"]["vertex_mm_gauge"] == pytest.approx(0, abs=1e-3)
    assert errors["gauge"]["unseen"]["vertex_mm"] > 0.1  # the offset is real, and the gauge removes it
    unseen = [t for t in capture.timesteps if t not in trained]
    model = FlameModel.load(run_root / "head.pkl")
    direct = np.mean([frame_errors(model, start(t), truth[t])["vertex_mm"] for t in unseen])
    assert errors["start"]["unseen"]["timesteps"] == len(unseen)
    assert errors["start"]["training"]["timesteps"] == len(trained)
    assert errors["start"]["unseen"]["vertex_mm"] == pytest.approx(direct, rel=1e-6)
    record = json.loads((refined / RECORD_FILE).read_text())
    assert set(record["truth_errors"]) == {"tracked", "start", "refined"}
    assert record["truth_errors"]["tracked"]["unseen"]["vertex_mm"] == pytest.approx(direct, rel=1e-5)
    aligned = AlignedTrackedParams(capture, run).params_for  # the start: tracked + the mean fine-tuning offset
    moved = np.mean([frame_errors(model, aligned(t), truth[t])["vertex_mm"] for t in unseen])
    assert moved != pytest.approx(direct, rel=1e-4)  # the fake run's nudge of timestep 0 moves it (a little)
    assert record["truth_errors"]["start"]["unseen"]["vertex_mm"] == pytest.approx(moved, rel=1e-5)


def test_cancelling_the_worker_stops_the_child_and_keeps_nothing_half_done(run_root, tmp_path):
    import time

    from mogaface.core.for_blender.worker import refine_tracking_command

    bare = tmp_path / "run"
    shutil.copytree(run_root, bare)
    (bare / "refiner.pt").unlink()  # the child trains one with the defaults first: long enough to cancel
    worker = RefineTrackingWorker(refine_tracking_command(sys.executable, bare, threads=1), bare).start()
    try:
        deadline = time.monotonic() + 120
        while worker.poll().step < 1 and not worker.progress.finished and time.monotonic() < deadline:
            time.sleep(0.1)
        assert worker.progress.stage == "refiner offsets", (worker.progress, worker.stderr_tail())
        worker.cancel()
        progress = worker.wait(interval=0.1, timeout=60)
    finally:
        worker.kill()
    assert progress.state == "cancelled", (progress.message, worker.stderr_tail())
    assert "nothing replaced" in progress.message and progress.stage.startswith("refiner")
    assert not (bare / "refiner.pt").exists() and not (bare / "refined_tracking").exists()
    assert not list(bare.glob(".refine*"))
