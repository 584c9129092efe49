"""Guards of the measurements: no image-assisted source and no part of the refiner reads a
synthetic capture's answers (``flame_param_gt/``, ``cameras_gt.json``, ``camera_colour_gt.json``); scores kept by the ablation
are not used again once the scoring code changed; the seed statistics never call a difference
"beyond noise" they cannot test."""

import contextlib
import json
import pathlib
import shutil
import sys

import numpy as np
import pytest
import torch
from test_evaluate_fixtures import fake_run, tiny_capture

from mogaface.core.data.camera_colour import GT_COLOUR_FILE
from mogaface.core.data.capture import Capture
from mogaface.core.data.generator import GT_CAMERAS_FILE, GT_FLAME_DIR
from mogaface.core.evaluate import benchmark
from mogaface.core.evaluate.protocols import protocol_frames
from mogaface.core.evaluate.seed_stats import format_difference, paired_difference
from mogaface.core.run.folder import RunFolder

# -- the file-access spy -------------------------------------------------------------------------
# Every open of the process passes the "open" audit event (builtins.open, io.open, os.open, and so
# np.load, torch.load, PIL), a folder listing "os.listdir"/"os.scandir". An audit hook cannot be
# removed, so one hook is added once and records only while a recorder is active.
_RECORDERS: list[list[str]] = []


def _audit(event, args):
    if _RECORDERS and event in ("open", "os.listdir", "os.scandir") and args and isinstance(args[0], (str, bytes, pathlib.PurePath)):
        path = args[0].decode() if isinstance(args[0], bytes) else str(args[0])
        for recorder in _RECORDERS:
            recorder.append(path)


if not getattr(sys, "_mogaface_test_audit", False):
    sys.addaudithook(_audit)
    sys._mogaface_test_audit = True


@contextlib.contextmanager
def opened_files():
    """Every path the process opens or lists inside the block."""
    recorder: list[str] = []
    _RECORDERS.append(recorder)
    try:
        yield recorder
    finally:
        _RECORDERS.remove(recorder)


def answers(paths: list[str]) -> list[str]:
    """The paths among ``paths`` that are a synthetic capture's answers."""
    return [p for p in paths if GT_FLAME_DIR in pathlib.PurePath(p).parts
            or pathlib.PurePath(p).name in (GT_CAMERAS_FILE, GT_COLOUR_FILE)]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return Capture.open(tiny_capture(tmp_path_factory))


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """The fake run with a refiner trained beside it, the training watched by the spy."""
    from mogaface.core.refiner.training import RefinerSettings, train_refiner

    root = tmp_path_factory.mktemp("guarded") / "run"
    shutil.copytree(fake_run(tmp_path_factory), root)
    with opened_files() as seen:
        train_refiner(root, RefinerSettings(starts=2, offsets_per_start=2, gap_timesteps=2, curvature_timesteps=1,
                                            threads=1, spec={"grid": 4, "render_limit": 64, "prior": 1.0,
                                                             "gap_rank": 1}))
    return RunFolder(root), seen


def image_assisted_sources(capture, run):
    """name → source: every source an image-assisted result is made of, as the benchmark and
    ``refine-tracking`` build them (smoothing with fixed σ: choosing σ reads the truth of the
    training sequences by design, see :func:`..sources.smoothed.choose_sigmas`)."""
    from mogaface.core.correction.model import MoGaFace
    from mogaface.core.evaluate.sources.corrected import MoGaFaceParams
    from mogaface.core.evaluate.sources.fitted import FittedParams
    from mogaface.core.evaluate.sources.refined import RefinedParams, RefinerInference, run_refiner
    from mogaface.core.evaluate.sources.smoothed import SmoothedParams
    from mogaface.core.evaluate.sources.tracked import AlignedTrackedParams, TrackedParams
    from mogaface.core.run.cameras import InputCameras

    avatar = run.load_avatar()
    inputs = InputCameras.of_run(capture, run.root)
    start = AlignedTrackedParams(capture, run)
    refiner = run_refiner(run.root, avatar)
    spec = {"mode": "multi", "bank": True, "texture": False, "input_size": 16, "feature_dim": 8, "encoder_width": 4,
            "heads": 2, "hidden": 8, "plane_size": 4, "plane_dim": 2, "texture_hidden": 4, "n_expr": avatar.flame.n_expr}
    cameras = sorted({f.camera_id for f in capture.frames("train")})
    with torch.no_grad():
        rest = avatar.flame()[0]
    torch.manual_seed(0)
    model = MoGaFace(spec, run.trained_timesteps, cameras, rest)
    with torch.no_grad():  # an untrained head regresses zero: make it answer something
        model.head.out.weight.normal_(std=0.1)
    return avatar, {
        "tracked": TrackedParams(capture, run),
        "tracked_aligned": start,
        "smoothed": SmoothedParams(capture, TrackedParams(capture, run), {"expr": 1.0, "pose": 1.0, "translation": 1.0}),
        "fit_2": FittedParams(avatar, capture, start, 2, run.background, cameras=inputs),
        "refined_1": RefinedParams(avatar, capture, start, refiner, run.background, 1, cameras=inputs),
        "refined_fit_1": RefinerInference(avatar, capture, run, refiner, passes=1, fit_steps=1, cameras=inputs),
        "method": MoGaFaceParams(capture, run, model, image_assisted=True),
    }


def test_refiner_training_reads_no_answers(trained):
    _, seen = trained
    assert seen, "the spy saw no file at all"
    assert any(path.endswith("avatar.pt") for path in seen)  # it does see what training reads
    assert answers(seen) == []


def test_no_image_assisted_source_reads_the_answers(capture, trained):
    """Each source on one frame of both protocols (built and asked under the spy): the files it
    reads include the capture's images, never ``flame_param_gt/`` or ``cameras_gt.json``."""
    run, _ = trained
    frames = [protocol_frames(capture, "self_reenactment")[0], protocol_frames(capture, "novel_view")[0]]
    with opened_files() as seen:
        _, sources = image_assisted_sources(capture, run)
    assert answers(seen) == []
    for name in sources:
        fresh = Capture.open(capture.root)  # a capture that has read no image yet
        source = image_assisted_sources(fresh, run)[1][name]
        with opened_files() as seen:
            for frame in frames:
                params = source.params_for(frame, exclude_view=frame.camera_id)
                assert np.isfinite(params["expr"]).all(), name
            params = source.params_for(frames[0].timestep_index)  # a timestep, as refine-tracking asks
        assert answers(seen) == [], name
        if source.uses_images:
            assert any(pathlib.PurePath(p).suffix == ".png" for p in seen), f"{name} read no image"
            assert source.inputs, f"{name} recorded no input views"


def test_the_spy_catches_a_source_that_reads_the_answers(capture, trained):
    """Negative control: fitting started from the truth, and the scoring cameras, are caught."""
    from mogaface.core.evaluate.sources.fitted import FittedParams
    from mogaface.core.evaluate.sources.true import TrueParams
    from mogaface.core.run.cameras import ScoringCameras

    run, _ = trained
    avatar = run.load_avatar()
    frame = protocol_frames(capture, "self_reenactment")[0]
    cheat = FittedParams(avatar, capture, TrueParams(capture, run), 1, run.background)
    with opened_files() as seen:
        cheat.params_for(frame, exclude_view=frame.camera_id)
    assert answers(seen) and all(GT_FLAME_DIR in p for p in answers(seen))
    with opened_files() as seen:
        ScoringCameras(capture)
    assert {pathlib.PurePath(p).name for p in answers(seen)} == {GT_CAMERAS_FILE}


# -- the ablation's kept scores ------------------------------------------------------------------
def test_scoring_code_hash_covers_the_scoring_modules(tmp_path):
    """The hash over a copy of the scoring files equals the real one; an edit of any of
    protocols, metrics or a source changes it."""
    copy = tmp_path / "core"
    for pattern in benchmark.SCORING_CODE:
        for path in benchmark.CORE.glob(pattern):
            target = copy / path.relative_to(benchmark.CORE)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, target)
    real = benchmark.scoring_code_hash()
    assert benchmark.scoring_code_hash(root=copy) == real
    for name in ("evaluate/protocols.py", "metrics/images.py", "evaluate/sources/fitted.py",
                 "evaluate/sources/refined.py", "refiner/inference.py"):
        text = (copy / name).read_text()
        (copy / name).write_text(text + "\n# edited\n")
        assert benchmark.scoring_code_hash(root=copy) != real, name
        (copy / name).write_text(text)
    assert benchmark.scoring_code_hash(root=copy) == real
    with pytest.raises(FileNotFoundError):
        benchmark.scoring_code_hash(["evaluate/no_such_module.py"])


def test_ablation_scores_are_not_reused_after_the_scoring_code_changed(tmp_path, monkeypatch):
    from mogaface.core.evaluate import expression_error
    from mogaface.core.workflows.ablation import SCORES_FILE, score_variant

    code = tmp_path / "code"
    (code / "metrics").mkdir(parents=True)
    (code / "metrics" / "images.py").write_text("def psnr(): return 1\n")
    monkeypatch.setattr(benchmark, "CORE", code)
    monkeypatch.setattr(benchmark, "SCORING_CODE", ("metrics/images.py",))
    calls = []
    monkeypatch.setattr(benchmark, "benchmark_run", lambda run_dir, **options: calls.append(run_dir) or
                        {"protocols": {"self_reenactment": {"tracked": {"psnr": 20.0 + len(calls)}}}})
    monkeypatch.setattr(expression_error, "expression_errors", lambda run_dir: {"expr_rmse_tracked": 0.5})
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text(json.dumps({"complete": True}))

    def psnr():
        return score_variant(run, 2, False, (1,))["protocols"]["self_reenactment"]["tracked"]["psnr"]

    assert psnr() == 21.0 and len(calls) == 1
    assert psnr() == 21.0 and len(calls) == 1  # unchanged code: the kept scores
    (code / "metrics" / "images.py").write_text("def psnr(): return 2\n")
    assert psnr() == 22.0 and len(calls) == 2  # the scoring code changed: scored again
    kept = json.loads((run / SCORES_FILE).read_text())
    assert kept["options"]["scoring_code"] == benchmark.scoring_code_hash()


# -- seed statistics -----------------------------------------------------------------------------
def test_a_difference_without_spread_or_with_one_seed_is_not_called_beyond_noise():
    same = paired_difference([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    assert same["mean"] == 0 and same["std"] == 0 and same["beyond_noise"] is None
    assert format_difference(same, 2) == "+0.00 ± 0.00 (n/a)"
    constant = paired_difference([1.5, 2.5, 3.5], [1.0, 2.0, 3.0])  # every seed +0.5: the t-test has no scale
    assert constant["beyond_noise"] is None and format_difference(constant, 2) == "+0.50 ± 0.00 (n/a)"
    one = paired_difference([1.5], [1.0])
    assert one["n"] == 1 and one["beyond_noise"] is None and format_difference(one, 2) == "+0.50 (n/a)"
    clear = paired_difference([1.5, 2.6, 3.4], [1.0, 2.0, 3.0])
    assert clear["beyond_noise"] is True and format_difference(clear, 2).endswith(" *")
    noisy = paired_difference([1.5, 1.0, 3.4], [1.0, 2.0, 3.0])
    assert noisy["beyond_noise"] is False and format_difference(noisy, 2).endswith("(n.s.)")
    assert format_difference(paired_difference([None], [1.0]), 2) == "–"
