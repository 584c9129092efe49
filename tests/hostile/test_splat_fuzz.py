"""The splat engine on degenerate Gaussians and intrinsics: every case finishes (each under a
deadline the harness enforces on a child process) with finite images and gradients."""

from mogaface.bench.splat_fuzz import make_case, run_with_deadline

SEEDS = range(60)  # includes hangs found before: focal >= 1e21 px, means/scales of 1e30


def test_fuzz_cases_finish_with_finite_outputs_and_gradients():
    report = run_with_deadline(SEEDS, per_case_s=20.0)
    assert report["hang_or_crash_seed"] is None, f"case {report['hang_or_crash_seed']} hung or crashed"
    bad = [r["seed"] for r in report["results"] if not (r["images_finite"] and r["grads_finite"])]
    assert bad == []
    assert len(report["results"]) == len(SEEDS)


def test_fuzz_covers_the_cases_that_used_to_hang():
    focals = [max(make_case(s)["K"][:2]) for s in SEEDS]
    assert max(focals) >= 1e21
    assert any(max(abs(x) for row in make_case(s)["means"] for x in row) >= 1e30 for s in SEEDS)
