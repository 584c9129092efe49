"""Parameter sources below the protocols: smoothing and test-time fitting improve a known-noisy
input, the ceiling renders with the truth, frames are scored from the true camera, and no scored
view ever reaches a source."""

import json

import numpy as np
import pytest
from test_evaluate_fixtures import capture_fixture, fake_run, random_avatar, run_fixture, tiny_capture  # noqa: F401 (fixtures)

from mogaface.core.avatar.avatar import render_frame
from mogaface.core.data.capture import Capture
from mogaface.core.data.generator import CaptureSettings, make_capture
from mogaface.core.evaluate.benchmark import benchmark_run, standard_sources
from mogaface.core.evaluate.expression_error import frame_errors
from mogaface.core.evaluate.protocols import protocol_frames, run_protocol
from mogaface.core.evaluate.sources import smoothed as smoothed_module
from mogaface.core.evaluate.sources.fitted import PRIOR_WEIGHT, FittedParams
from mogaface.core.evaluate.sources.smoothed import SmoothedParams, choose_sigmas, sequence_timesteps
from mogaface.core.evaluate.sources.true import TrueParams, true_params
from mogaface.core.run.cameras import ScoringCameras
from mogaface.core.run.folder import MOTION_KEYS, RunFolder


class Offset:
    """The truth plus a known error (what a tracker with that error would report)."""

    uses_images = False
    description = "known offset"

    def __init__(self, capture, expr=0.6, rotation=0.03, translation=0.002):
        self.capture, self.expr, self.rotation, self.translation = capture, expr, rotation, translation

    def params_for(self, frame, exclude_view=None):
        t = frame if isinstance(frame, int) else frame.timestep_index
        p = dict(true_params(self.capture, t))
        signs = np.where(np.arange(len(p["expr"])) % 2 == 0, 1.0, -1.0).astype(np.float32)
        p["expr"] = p["expr"] + self.expr * signs
        p["rotation"] = p["rotation"] + np.float32(self.rotation)
        p["translation"] = p["translation"] + np.float32(self.translation)
        return p


class RenderedCapture:
    """The capture with every image replaced by ``avatar``'s render at the true parameters (so a
    perfect fit exists); records every image a source loads."""

    def __init__(self, capture, avatar):
        self.capture, self.avatar, self.loaded = capture, avatar, []

    def __getattr__(self, name):
        return getattr(self.capture, name)

    def load_image(self, frame):
        self.loaded.append((frame.timestep_index, frame.camera_id))
        return render_frame(self.avatar, true_params(self.capture, frame.timestep_index), self.capture.camera(frame),
                            (1.0, 1.0, 1.0))


def test_test_time_fitting_improves_a_known_noisy_input(capture, run):
    avatar = random_avatar(run.root / "head.pkl", seed=1)
    rendered = RenderedCapture(capture, avatar)
    frame = protocol_frames(capture, "self_reenactment")[0]
    truth = true_params(capture, frame.timestep_index)
    start = frame_errors(avatar.flame, Offset(capture).params_for(frame), truth)
    source = FittedParams(avatar, rendered, Offset(capture), steps=10, background=(1.0, 1.0, 1.0),
                          views_per_step=2, scale=1.0)
    fitted = source.params_for(frame, exclude_view=frame.camera_id)
    after = frame_errors(avatar.flame, fitted, truth)
    assert after["vertex_mm"] < 0.5 * start["vertex_mm"], (start, after)
    assert after["expr_rmse"] < 0.8 * start["expr_rmse"], (start, after)
    np.testing.assert_array_equal(fitted["shape"], truth["shape"])  # identity is not fitted
    # Only the other views of the timestep were looked at.
    assert rendered.loaded and (frame.timestep_index, frame.camera_id) not in rendered.loaded
    assert {t for t, _ in rendered.loaded} == {frame.timestep_index}
    assert source.inputs == [(frame.camera_id, [c for c in capture.cameras if c != frame.camera_id])]  # all: no limit
    # The avatar is frozen: fitting changed none of its weights.
    assert all(p.grad is None or not p.grad.any() for p in avatar.parameters())


def test_test_time_fitting_stays_near_a_right_start_the_avatar_cannot_match(capture, run):
    """Images the avatar cannot reproduce (another avatar rendered them) pull the parameters away
    from a start that is already right; the prior toward the start holds them near it."""
    avatar = random_avatar(run.root / "head.pkl", seed=1)
    rendered = RenderedCapture(capture, random_avatar(run.root / "head.pkl", seed=2))
    frame = protocol_frames(capture, "self_reenactment")[0]
    truth = true_params(capture, frame.timestep_index)
    exact = Offset(capture, expr=0.0, rotation=0.0, translation=0.0)
    drift = {}
    # the prior's pull at 1e-3; the default (chosen on validation frames, where the avatar does match
    # its captures) is weaker and holds less
    for name, weight in {"no prior": 0.0, "prior": 1e-3, "default": PRIOR_WEIGHT}.items():
        source = FittedParams(avatar, rendered, exact, steps=20, background=(1.0, 1.0, 1.0), views_per_step=2,
                              scale=1.0, prior_weight=weight)
        drift[name] = frame_errors(avatar.flame, source.params_for(frame, exclude_view=frame.camera_id), truth)
    assert drift["no prior"]["vertex_mm"] > 0.05, drift  # the mismatch does pull
    assert drift["prior"]["vertex_mm"] < 0.5 * drift["no prior"]["vertex_mm"], drift
    assert drift["prior"]["expr_rmse"] < 0.5 * drift["no prior"]["expr_rmse"], drift
    assert drift["prior"]["vertex_mm"] <= drift["default"]["vertex_mm"] <= drift["no prior"]["vertex_mm"], drift


def test_smoothing_improves_a_known_noisy_input(tmp_path):
    settings = CaptureSettings(views=2, timesteps=120, size=32, supersample=1,
                               **CaptureSettings.iid_noise(expr_noise=0.5, pose_noise=0.02))
    capture = Capture.open(make_capture(tmp_path / "iid", settings, progress=False))
    sigmas = choose_sigmas(capture, held_out=["FREE"])
    assert sigmas["expr"] > 0 and sigmas["pose"] > 0  # independent noise: some smoothing pays on training sequences
    free = sequence_timesteps(capture)["FREE"]
    tracked = _Tracked(capture)
    source = SmoothedParams(capture, tracked, sigmas)
    for key, group in (("expr", "expr"), ("jaw_pose", "pose")):
        before = np.sqrt(np.mean([np.square(tracked.params_for(t)[key] - true_params(capture, t)[key]) for t in free]))
        after = np.sqrt(np.mean([np.square(source.params_for(t)[key] - true_params(capture, t)[key]) for t in free]))
        assert after < 0.8 * before, (key, before, after)
    assert "expr" in source.description


def test_smoothing_sigma_is_never_chosen_on_the_held_out_sequence(capture, monkeypatch, tmp_path_factory):
    read = []
    real = smoothed_module.true_params

    def spy(cap, timestep):
        read.append(timestep)
        return real(cap, timestep)

    monkeypatch.setattr(smoothed_module, "true_params", spy)
    choose_sigmas(capture, held_out=["FREE"])
    free = set(sequence_timesteps(capture)["FREE"])
    assert read and not free & set(read)
    read.clear()  # the benchmark's smoothing: neither the test nor the validation sequence
    standard_sources(RunFolder(fake_run(tmp_path_factory)), capture, random_avatar(capture.root / "head.pkl"),
                     fit_steps=())
    unseen = free | set(sequence_timesteps(capture)["VAL"])
    assert read and not unseen & set(read)


class _Tracked:
    uses_images = False

    def __init__(self, capture):
        self.capture = capture

    def params_for(self, frame, exclude_view=None):
        return dict(self.capture.flame_params(frame if isinstance(frame, int) else frame.timestep_index))


def test_the_ceiling_renders_with_the_true_parameters(capture, run):
    avatar = run.load_avatar()
    frames = protocol_frames(capture, "self_reenactment", max_frames=2)
    identity = run.identity_params()
    for item in run_protocol(avatar, capture, TrueParams(capture, run), frames, run.background):
        truth = true_params(capture, item.frame.timestep_index)
        for key in MOTION_KEYS:
            np.testing.assert_array_equal(item.params[key], truth[key])
        np.testing.assert_array_equal(item.params["shape"], identity["shape"])
        expected, _ = render_frame(avatar, {**truth, **identity}, ScoringCameras(capture)(item.frame), run.background)
        np.testing.assert_array_equal(item.prediction, expected)
    assert not np.allclose(capture.flame_params(frames[0].timestep_index)["expr"], true_params(capture, frames[0].timestep_index)["expr"])


def test_camera_noise_is_scored_from_the_true_held_out_pose(tmp_path_factory, run):
    root = tmp_path_factory.mktemp("camera_noise")
    noisy = Capture.open(make_capture(root, CaptureSettings(views=3, timesteps=16, size=48, supersample=1,
                                                            camera_noise=2.0), progress=False))
    avatar = run.load_avatar()
    frame = protocol_frames(noisy, "novel_view", max_frames=1)[0]
    true_camera = ScoringCameras(noisy)(frame)
    assert not np.allclose(true_camera.w2c, noisy.camera(frame).w2c)  # the calibration is off
    source = _Tracked(noisy)
    item = next(run_protocol(avatar, noisy, source, [frame], run.background))
    params = source.params_for(frame)
    np.testing.assert_array_equal(item.prediction, render_frame(avatar, params, true_camera, run.background)[0])
    assert not np.allclose(item.prediction, render_frame(avatar, params, noisy.camera(frame), run.background)[0])
    from mogaface.core.evaluate.camera_error import camera_errors

    calibrated = camera_errors(noisy)["calibrated"]
    assert calibrated["cameras"] == 3 and 0.5 < calibrated["rotation_deg"] < 8.0


def test_true_cameras_follow_the_captures_cy_convention(tmp_path):
    """A capture written with ``cy`` from the top edge says so in its split files; its true cameras
    (``cameras_gt.json``) are read the same way, so scoring cameras match the calibrated ones."""
    import json

    root = make_capture(tmp_path / "cap", CaptureSettings(views=3, timesteps=16, size=48, supersample=1),
                        progress=False)
    bottom = Capture.open(root)
    for path in [*root.glob("transforms*.json"), root / "cameras_gt.json"]:
        doc = json.loads(path.read_text())
        entries = doc.values() if path.name == "cameras_gt.json" else [doc, *doc.get("frames", [])]
        for entry in entries:
            if "cy" in entry:
                entry["cy"] = entry.get("h", doc.get("h")) - entry["cy"]
        if path.name != "cameras_gt.json":
            doc["cy_origin"] = "top"
        path.write_text(json.dumps(doc))
    top = Capture.open(root)
    frame = top.frames()[0]
    assert abs(2 * bottom.camera(frame).cy - 48) > 0.01  # off-centre: the two readings differ
    truth = ScoringCameras(top)
    assert truth.truth  # the synthetic capture keeps its true cameras
    np.testing.assert_allclose(truth(frame).K, top.camera(frame).K)
    np.testing.assert_allclose(top.camera(frame).K, bottom.camera(frame).K)


@pytest.fixture(scope="module")
def run_with_refiner(run, tmp_path_factory):
    """The fake run with a refiner beside it (a few rendered offsets): the refined sources join in."""
    import shutil

    from mogaface.core.refiner.training import RefinerSettings, train_refiner

    root = tmp_path_factory.mktemp("with_refiner") / "run"
    shutil.copytree(run.root, root)
    train_refiner(root, RefinerSettings(starts=2, offsets_per_start=2, gap_timesteps=2, threads=1,
                                        spec={"grid": 4, "render_limit": 64, "prior": 1.0, "gap_rank": 1}))
    return RunFolder(root)


def test_no_scored_view_reaches_any_source(capture, run_with_refiner, monkeypatch):
    """Every standard source, on both protocols: the scored image is never loaded while the
    source computes that frame's parameters, and every request names the scored view."""
    run = run_with_refiner
    avatar = run.load_avatar()
    loaded = []
    real = Capture.load_image

    def spy(self, frame):
        loaded.append((frame.timestep_index, frame.camera_id))
        return real(self, frame)

    monkeypatch.setattr(Capture, "load_image", spy)
    sources = standard_sources(run, capture, avatar, fit_steps=(1,))
    assert set(sources) == {"tracked", "tracked_aligned", "smoothed", "fit_1", "refined_1", "refined_3",
                            "refined_fit_1", "true", "true_gauge"}
    checked = []
    source_of = dict(sources)
    for name, source in sources.items():
        real_params = source.params_for

        def guarded(frame, exclude_view=None, _real=real_params, _name=name):
            before = len(loaded)
            params = _real(frame, exclude_view=exclude_view)
            seen = loaded[before:]
            if isinstance(frame, int):  # a source asking its image-free base for a timestep
                assert not seen, _name
                return params
            assert exclude_view == frame.camera_id, _name
            assert (frame.timestep_index, frame.camera_id) not in seen, _name
            if _name.startswith(("fit", "refined")):
                assert seen, f"{_name} looked at no view"
                scored, looked_at = source_of[_name].inputs[-1]
                assert scored == frame.camera_id and frame.camera_id not in looked_at, _name
            checked.append(_name)  # image-using bases (refined_fit_1's refiner) are checked here too
            return params

        monkeypatch.setattr(source, "params_for", guarded)
    result = benchmark_run(run.root, max_frames=2, lpips=False, sources=sources, avatar=avatar)
    assert {name: checked.count(name) >= 2 * 2 for name in sources} == {name: True for name in sources}
    free = result["protocols"]["self_reenactment"]
    assert free["true"]["vertex_mm"] == pytest.approx(0.0, abs=1e-6) and free["tracked"]["vertex_mm"] > 0.1
    # the truth in the gauge is off the raw truth by the run's mean offset, and its own gauge error is none
    assert free["true_gauge"]["vertex_mm_gauge"] == pytest.approx(0.0, abs=1e-6)
    assert free["true_gauge"]["vertex_mm"] > 1e-3
    assert free["tracked"]["vertex_mm_gauge"] != pytest.approx(free["tracked"]["vertex_mm"])
    assert all(scores["frame_s"] > 0 for scores in free.values())
    named = result["scored"]["self_reenactment"]
    assert len(named["frames"]) == 2 and named["frames"][0].startswith("FREE_") and "FREE" in named["label"]
    assert result["scored"]["novel_view"]["label"] == "novel view: held-out camera cam01 on training frames"


def test_image_assisted_sources_see_their_input_views_through_the_runs_refined_cameras(
        capture, run_with_refiner, tmp_path, monkeypatch):
    """With ``RUN/cameras_refined.json`` the other views are rendered from the refined poses (the
    avatar was trained against them); without it, from the calibration."""
    import shutil

    from mogaface.core.camera import Camera
    from mogaface.core.data.camera_file import camera_fields
    from mogaface.core.evaluate.sources import refined as refined_module

    root = tmp_path / "run"
    shutil.copytree(run_with_refiner.root, root)
    frame = next(f for f in capture.frames("val"))
    calibrated = capture.camera_at("cam00", frame.timestep_index)
    moved = calibrated.w2c.copy()
    moved[:3, 3] += (0.01, -0.02, 0.005)
    (root / "cameras_refined.json").write_text(json.dumps(
        {"cam00": camera_fields(Camera(calibrated.K, moved, calibrated.width, calibrated.height, "cam00"))}))
    run = RunFolder(root)
    avatar = run.load_avatar()
    seen = {"fit": [], "refined": []}
    render = avatar.render
    monkeypatch.setattr(avatar, "render", lambda params, camera, bg: seen["fit"].append(camera) or render(params, camera, bg))
    refine = refined_module.refine
    monkeypatch.setattr(refined_module, "refine",
                        lambda a, r, p, cameras, *rest: seen["refined"].extend(cameras) or refine(a, r, p, cameras, *rest))
    sources = standard_sources(run, capture, avatar, fit_steps=(2,))
    for name in ("fit_2", "refined_1"):
        sources[name].params_for(frame, exclude_view=frame.camera_id)
    fitted = {c.camera_id: c for c in seen["fit"]}
    refined = {c.camera_id: c for c in seen["refined"]}
    np.testing.assert_allclose(fitted["cam00"].w2c, moved, atol=1e-9)  # fitting renders through the refined pose
    np.testing.assert_allclose(refined["cam00"].w2c, moved, atol=1e-9)
    np.testing.assert_allclose(refined["cam02"].w2c, capture.camera_at("cam02", frame.timestep_index).w2c)
    assert frame.camera_id not in fitted and frame.camera_id not in refined
    (root / "cameras_refined.json").unlink()
    seen["fit"].clear()
    standard_sources(run, capture, avatar, fit_steps=(2,))["fit_2"].params_for(frame, exclude_view=frame.camera_id)
    np.testing.assert_allclose({c.camera_id: c for c in seen["fit"]}["cam00"].w2c, calibrated.w2c)


def test_fitting_and_the_refiner_read_the_same_views(capture, run_with_refiner):
    """Like for like: per frame both read the same other views, of the training cameras only (the
    held-out camera's unseen frames are scored, never read), at most INPUT_VIEWS of them."""
    from mogaface.core.evaluate.sources.base import INPUT_VIEWS, input_views, training_cameras

    run = run_with_refiner
    sources = standard_sources(run, capture, run.load_avatar(), fit_steps=(1,))
    held_out = {f.camera_id for f in capture.frames("val")}
    assert training_cameras(capture) == sorted(set(capture.cameras) - held_out) == ["cam00", "cam02"]
    for frame in protocol_frames(capture, "self_reenactment"):
        for name in ("fit_1", "refined_1", "refined_3", "refined_fit_1"):
            sources[name].params_for(frame, exclude_view=frame.camera_id)
        reads = {name: sources[name].inputs[-1] for name in ("fit_1", "refined_1", "refined_3", "refined_fit_1")}
        assert len({(scored, tuple(read)) for scored, read in reads.values()}) == 1, reads
        scored, read = reads["fit_1"]
        assert scored == frame.camera_id and frame.camera_id not in read and not held_out & set(read)
        assert read == [f.camera_id for f in input_views(capture, frame.timestep_index, frame.camera_id,
                                                         INPUT_VIEWS, training_cameras(capture))]
        assert read  # every FREE frame has another training view to read


def test_input_views_are_spread_over_the_rig(capture):
    from mogaface.core.evaluate.sources.base import input_views

    t = protocol_frames(capture, "self_reenactment")[0].timestep_index
    assert [f.camera_id for f in input_views(capture, t, "cam01")] == ["cam00", "cam02"]
    assert [f.camera_id for f in input_views(capture, t, None, 2)] == ["cam00", "cam02"]  # ends of the rig
    assert [f.camera_id for f in input_views(capture, t, None, cameras=["cam01"])] == ["cam01"]
    assert input_views(capture, t, "cam01", cameras=["cam01"]) == []


def test_scored_views_name_what_a_protocol_scores(capture):
    from mogaface.core.evaluate.protocols import scored_views

    free = protocol_frames(capture, "self_reenactment")
    everything = scored_views(capture, free)
    assert everything["cameras"] == ["cam00", "cam01", "cam02"]
    assert everything["frames"][0] == f"{free[0].timestep_id}/{free[0].camera_id}" and len(everything["frames"]) == 12
    assert everything["label"].startswith("self-reenactment and novel view of unseen frames") and "FREE" in everything["label"]
    own = scored_views(capture, [f for f in free if f.camera_id != "cam01"])
    assert own["label"] == "self-reenactment: training cameras on unseen frames (FREE)"
    held = scored_views(capture, [f for f in free if f.camera_id == "cam01"])
    assert held["label"] == "novel view of unseen frames: held-out camera cam01 on unseen frames (FREE)"
    novel = scored_views(capture, protocol_frames(capture, "novel_view"))
    assert novel["label"] == "novel view: held-out camera cam01 on training frames" and novel["cameras"] == ["cam01"]


def test_eval_names_the_frames_and_cameras_it_scored(run, tmp_path):
    from mogaface.core.evaluate.evaluation import evaluate_run

    evaluate_run(run.root, ["novel_view", "self_reenactment"], 3, lpips=False, out_dir=tmp_path, comparisons=0)
    written = json.loads((tmp_path / "metrics.json").read_text())["protocols"]
    for name, summary in written.items():
        rows = summary["per_frame"]
        assert len(summary["scored"]["frames"]) == len(rows) == summary["frames"], name
        assert summary["scored"]["cameras"] == sorted({r["camera"] for r in rows}), name
        assert [f.split("/")[1] for f in summary["scored"]["frames"]] == [r["camera"] for r in rows], name
    assert written["self_reenactment"]["scored"]["label"].endswith("unseen frames (FREE)")
    assert written["novel_view"]["scored"]["label"].startswith("novel view: held-out camera cam01")


def test_the_validation_split_scores_the_validation_sequence_only(capture, run, tmp_path):
    """``split="validation"``: self-reenactment of VAL (every camera); the test frames never hold
    VAL; the held-out camera at training timesteps has no validation frames (skipped, said why)."""
    from mogaface.core.errors import InputError
    from mogaface.core.evaluate.evaluation import evaluate_run
    from mogaface.core.evaluate.protocols import protocol_unavailable, scored_views

    val = protocol_frames(capture, "self_reenactment", split="validation")
    test = protocol_frames(capture, "self_reenactment")
    assert {f.sequence for f in val} == {"VAL"} and len(val) == 2 * 3
    assert {f.sequence for f in test} == {"FREE"} and len(test) == 4 * 3
    assert scored_views(capture, val)["label"].endswith("unseen frames (VAL)")
    assert "only self_reenactment" in protocol_unavailable(capture, "novel_view", "validation")
    with pytest.raises(InputError, match="split"):
        protocol_frames(capture, "self_reenactment", split="FREE")
    result = evaluate_run(run.root, ["novel_view", "self_reenactment"], None, lpips=False, out_dir=tmp_path,
                          comparisons=0, split="validation")
    written = json.loads((tmp_path / "metrics.json").read_text())
    assert written["split"] == "validation" and list(written["protocols"]) == ["self_reenactment"]
    assert "novel_view" in written["skipped"] and result["protocols"]["self_reenactment"]["frames"] == 6
    assert {f.split("/")[0].split("_")[0] for f in written["protocols"]["self_reenactment"]["scored"]["frames"]} == {"VAL"}
    scored = benchmark_run(run.root, max_frames=2, lpips=False, fit_steps=(1,), split="validation")
    assert scored["split"] == "validation" and list(scored["protocols"]) == ["self_reenactment"]
    assert "novel_view" in scored["skipped"] and scored["scored"]["self_reenactment"]["label"].endswith("(VAL)")
