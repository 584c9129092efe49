"""Choosing settings and tabulating them: a refiner solved with other inference settings is the
generalised least-squares answer of its changed noise model (against numpy), the coordinate search
finds a grid's best and keeps an incumbent that others beat only within the margin, and the
parameter-source table gives each subject's mean ± std and the unseen subjects pooled."""

import json

import numpy as np
import pytest
import torch
from test_refiner import _random_refiner

from mogaface.bench.refiner_search import coordinate_search
from mogaface.bench.refiner_table import summary_table
from mogaface.core.errors import InputError
from mogaface.core.refiner.groups import scale_vector


def _gls(refiner, features, views):
    """The offset from numpy: prior·I + Σ AᵀΣ⁻¹A against Σ AᵀΣ⁻¹(f − g), Σ the full covariance."""
    size = refiner.forward.shape[2]
    normal, projected = refiner.spec["prior"] * np.eye(size), np.zeros(size)
    for row, camera in zip(features, views):
        i = refiner.camera_ids.index(camera)
        basis = refiner.gap_basis.numpy()[i].astype(np.float64)
        covariance = np.diag(refiner.residual.numpy()[i] + refiner.gap_var.numpy()[i]) + basis.T @ basis
        forward = refiner.forward.numpy()[i]
        normal += forward.T @ np.linalg.solve(covariance, forward)
        projected += forward.T @ np.linalg.solve(covariance, row - refiner.gap_mean.numpy()[i])
    return np.linalg.solve(normal, projected) * scale_vector(4).numpy()


def test_a_refiner_with_other_settings_solves_its_changed_noise_model():
    refiner = _random_refiner(4, gap=0.3, rank=2, curvature=1.0)
    features = np.random.default_rng(3).normal(size=(2, refiner.forward.shape[1]))
    views = ["b", "c"]
    for settings in ({"prior": 5.0}, {"gap_rank": 1}, {"gap_rank": 0, "prior": 0.5}):
        changed = refiner.with_settings(**settings)
        np.testing.assert_allclose(changed.offset(torch.as_tensor(features), views), _gls(changed, features, views),
                                   rtol=1e-4, atol=1e-6)
        # a smaller rank moves the dropped components' variance to the diagonal: the total is kept
        before = refiner.residual + refiner.gap_var + (refiner.gap_basis ** 2).sum(dim=1)
        after = changed.residual + changed.gap_var + (changed.gap_basis ** 2).sum(dim=1)
        torch.testing.assert_close(after, before)
    assert not np.allclose(refiner.with_settings(gap_rank=0).offset(torch.as_tensor(features), views),
                           refiner.offset(torch.as_tensor(features), views))
    assert refiner.full_size_steps(views) == 1 and refiner.with_settings(full_size_steps=0).full_size_steps(views) == 0
    assert refiner.with_settings(damping=0.5).spec["damping"] == 0.5 and refiner.spec["damping"] == 1e-3
    with pytest.raises(InputError, match="gap_rank"):
        refiner.with_settings(gap_rank=3)  # more components than were measured
    with pytest.raises(InputError, match="grid"):
        refiner.with_settings(grid=8)  # a training setting


def test_the_coordinate_search_finds_the_best_and_keeps_an_incumbent_within_the_margin():
    calls = []

    def evaluate(settings):
        calls.append(dict(settings))
        return {"psnr_db": 30.0 - (settings["a"] - 2) ** 2 - (settings["b"] - 1) ** 2}

    result = coordinate_search({"a": (0, 1, 2, 3), "b": (0, 1, 2)}, {"a": 0, "b": 0}, evaluate, rounds=2)
    assert result["chosen"] == {"a": 2, "b": 1} and result["chosen_psnr_db"] == 30.0
    assert len(calls) == len(result["tried"]) == len({tuple(sorted(c.items())) for c in calls})  # each once
    # a wider grid over what was tried: only the new values are evaluated
    known = {key: {"psnr_db": t["psnr_db"]} for key, t in
             ((json.dumps(t["settings"], sort_keys=True), t) for t in result["tried"])}
    calls.clear()
    wider = coordinate_search({"a": (0, 1, 2, 3, 4), "b": (0, 1, 2)}, {"a": 2, "b": 1}, evaluate, rounds=2, known=known)
    assert calls == [{"a": 4, "b": 1}] and wider["chosen"] == {"a": 2, "b": 1}
    assert [t["reused"] for t in wider["tried"]].count(False) == 1
    nearly = coordinate_search({"a": (0, 1)}, {"a": 0}, lambda s: {"psnr_db": 30.0 + 0.04 * s["a"]}, rounds=1)
    assert nearly["chosen"] == {"a": 0}  # +0.04 dB is within the margin: the incumbent stays
    assert coordinate_search({"a": (0, 1)}, {"a": 0}, lambda s: {"psnr_db": 30.0 + 0.2 * s["a"]},
                             rounds=1)["chosen"] == {"a": 1}


def _report(subject, psnr, run):
    return {"run": run, "capture": f"cap_s{subject}", "subject": {"subject": subject, "seed": subject},
            "frames": 12, "split": "test", "scored": {"label": "self-reenactment, FREE"},
            "psnr_db": {"tracked_aligned": psnr - 5, "refined_1": psnr, "fit_30": psnr - 0.1},
            "parameter_errors_mm": {"refined_1": {"vertex_mm": 2.0, "expr_vertex_mm": 0.5, "vertex_mm_gauge": 0.6,
                                                  "expr_vertex_mm_gauge": 0.3}},
            "seconds_per_frame": {"refined_1": 0.5, "fit_30": 4.0},
            "equal_quality": {"refined_1": {"fit_steps": 25.0, "status": "interpolated",
                                            "fitting_time_over_refiner": 7.0}},
            "load_average_before": [1.0], "load_average_after": [1.5]}


def test_the_table_gives_each_subject_and_the_unseen_ones_pooled():
    reports = [_report(0, 30.0, "a"), _report(1, 29.0, "b"), _report(1, 31.0, "c"), _report(2, 28.0, "d")]
    table = summary_table(reports)
    assert table["groups"] == {"subject 0 (tracker draw 0)": ["a"], "subject 1 (tracker draw 1)": ["b", "c"],
                               "subject 2 (tracker draw 2)": ["d"]}
    blocks = table["markdown"].split("**")
    pooled = table["markdown"][table["markdown"].index("pooled"):]
    assert "| **refiner, 1 pass** (the default) | 29.33 ± 1.53 |" in pooled  # b, c, d: not the tuning subject
    assert "| **refiner, 1 pass** (the default) | 30.00 ± 1.41 |" in table["markdown"]  # subject 1 alone
    assert "| 0.60 ± 0.00 | 0.30 ± 0.00 |" in pooled  # the gauge columns
    assert "+5.00 ± 0.00 (n/a)" in pooled  # against the start: no spread, the test cannot tell
    assert "25.0 ± 0.0 (interpolated) | 7.0 ± 0.0×" in pooled
    assert len(blocks) > 8 and "load 1.0–1.5" in table["markdown"]
    assert "pooled" not in summary_table(reports[:3])["markdown"]  # one unseen subject: nothing to pool


def test_kept_tries_of_other_searches_stay_in_the_file(tmp_path):
    from types import SimpleNamespace

    from mogaface.bench.refiner_search import TRIES_FILE, KeptTries

    def runs(*roots, frames=12):
        return [SimpleNamespace(folder=SimpleNamespace(root=root), frames=[0] * frames, fit_frames=[0] * 8)
                for root in roots]

    first, second = tmp_path / "a", tmp_path / "b"
    first.mkdir(), second.mkdir()
    # the one-search layout a file may still hold: kept, and read back under its own key
    earlier = KeptTries(runs(first, second))
    (first / TRIES_FILE).write_text(json.dumps({"key": earlier.key, "parts": {"refiner": {"x": {"psnr_db": 30.0}}}}))
    alone = KeptTries(runs(first))  # another search over the first run alone
    alone.evaluator("training", lambda settings: {"psnr_db": 31.0})({"grid": 8})
    both = KeptTries(runs(first, second))
    assert both.parts["refiner"] == {"x": {"psnr_db": 30.0}} and "training" not in both.parts
    assert KeptTries(runs(first)).parts["training"] == {'{"grid": 8}': {"psnr_db": 31.0}}
    assert KeptTries(runs(first, frames=4)).parts == {"refiner": {}, "fitting": {}}  # other frames: its own
