"""``ablate``: the ladder on a tiny capture with tiny settings and two seeds writes results.json (every
parameter source on both protocols, per seed), the table with mean ± std, and the figure."""

import json

import pytest

from mogaface.core.cli import main


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    from mogaface.core.data.generator import CaptureSettings, make_capture

    root = tmp_path_factory.mktemp("ablate_capture")
    make_capture(root, CaptureSettings(views=3, timesteps=16, size=48, supersample=1), progress=False)
    return root


def test_ablate_writes_results_table_and_figure(tiny_capture, tmp_path):
    settings = tmp_path / "tiny.toml"
    settings.write_text('[train]\nthreads = 1\n[mogaface]\ninput_size = 32\nfeature_dim = 16\nencoder_width = 4\n'
                        'heads = 2\nhidden = 16\nplane_size = 8\nplane_dim = 4\ntexture_hidden = 8\n')
    out = tmp_path / "ablation"
    args = ["ablate", str(tiny_capture), "--out", str(out), "--config", str(settings), "--steps", "3",
            "--max-frames", "2", "--no-lpips", "--quiet", "--fit-steps", "1,2", "--seeds", "2"]
    assert main([*args, "--variants", "freeze,full_prior"]) == 0
    results = json.loads((out / "results.json").read_text())
    assert list(results["variants"]) == ["freeze", "full_prior"]
    for name, entry in results["variants"].items():
        assert list(entry["seeds"]) == ["0", "1"]
        for seed, run in entry["seeds"].items():
            assert run["train"]["steps"] == 3
            tuned = name == "full_prior"  # fine-tuned its parameters: the aligned start is a row of its own
            sources = ["tracked", *(["tracked_aligned"] if tuned else []), "smoothed", "fit_1", "fit_2",
                       *(["method"] if tuned else []), "true", "true_gauge"]
            for protocol in ("novel_view", "self_reenactment"):
                assert list(run["protocols"][protocol]) == sources, (name, protocol)
                for source, scores in run["protocols"][protocol].items():
                    assert scores["frames"] == 2 and scores["psnr"] > 5, (name, seed, source)
                    assert scores["vertex_mm"] >= 0 and scores["vertex_mm_gauge"] >= 0 and scores["frame_s"] > 0
            assert run["training_expression"]["expr_rmse_tracked"] > 0
            for protocol, named in run["scored"].items():  # what each protocol scored, by name
                assert len(named["frames"]) == 2 and named["cameras"] and named["label"], protocol
            assert "unseen frames (FREE)" in run["scored"]["self_reenactment"]["label"]
    free = results["variants"]["freeze"]["seeds"]["0"]["protocols"]["self_reenactment"]
    assert free["true"]["vertex_mm"] == pytest.approx(0.0, abs=1e-6)  # the truth's own motion
    assert free["true_gauge"]["vertex_mm_gauge"] == pytest.approx(0.0, abs=1e-6)  # the ceiling, in the gauge
    assert free["tracked"]["vertex_mm"] > 0.1
    freeze = results["variants"]["freeze"]["seeds"]["0"]["training_expression"]
    assert freeze["expr_rmse_corrected"] == pytest.approx(freeze["expr_rmse_tracked"])  # Freeze corrects nothing
    table = (out / "results.md").read_text()
    assert "Seeds: Freeze 0, 1; Full + zero-mean prior (the presets) 0, 1" in table and " ± " in table and "test-time fitting, 2 steps" in table
    assert "true parameters in the avatar's gauge (the ceiling)" in table and "mesh vertex mm, gauge" in table and "the method's image-assisted inference" in table
    assert (out / "figure.png").stat().st_size > 0
    # A second call reuses the complete runs.
    before = (out / "runs" / "full_prior" / "seed1" / "run.json").stat().st_mtime_ns
    assert main([*args, "--variants", "full_prior"]) == 0
    assert (out / "runs" / "full_prior" / "seed1" / "run.json").stat().st_mtime_ns == before
    assert list(json.loads((out / "results.json").read_text())["variants"]) == ["freeze", "full_prior"]
    # The validation sequence: the same runs scored on VAL, into files of their own.
    test_results = (out / "results.json").read_text()
    assert main([*args, "--variants", "freeze", "--split", "validation"]) == 0
    assert (out / "results.json").read_text() == test_results
    validation = json.loads((out / "results_validation.json").read_text())
    assert validation["split"] == "validation" and list(validation["variants"]) == ["freeze"]
    run = validation["variants"]["freeze"]["seeds"]["0"]
    assert list(run["protocols"]) == ["self_reenactment"] and "novel_view" in run["skipped"]
    assert run["scored"]["self_reenactment"]["label"].endswith("unseen frames (VAL)")
    assert "**Validation frames**" in (out / "results_validation.md").read_text()
    assert (out / "figure_validation.png").stat().st_size > 0


def test_later_rungs_are_set_against_freeze_and_against_fine_tuning():
    from mogaface.core.workflows.ablation_table import markdown

    def seeds(psnrs):
        return {str(s): {"protocols": {p: {"tracked": {"psnr": v, "ssim": v / 50, "vertex_mm": 1.0}}
                                       for p in ("self_reenactment", "novel_view")}} for s, v in enumerate(psnrs)}

    results = {"split": "test", "variants": {
        "freeze": {"label": "Freeze", "seeds": seeds([26.0, 26.2])},
        "finetune": {"label": "Fine-tuning", "seeds": seeds([30.0, 30.4])},
        "full_prior": {"label": "Full", "seeds": seeds([30.5, 30.8])}}}
    table = markdown(results).split("**Held-out camera**")[1].split("**Training")[0]
    header = next(line for line in table.splitlines() if line.startswith("| variant"))
    assert header.endswith("| Δ PSNR / SSIM / LPIPS vs Freeze (same source) "
                           "| Δ PSNR / SSIM / LPIPS vs fine-tuning (same source) |")
    rows = {cells[0]: cells for cells in ([c.strip() for c in line.strip("|").split("|")]
                                          for line in table.splitlines() if line.startswith("| ") and "---" not in line)}
    assert rows["Freeze"][-2:] == ["", ""]  # no reference for the first rung
    assert rows["Fine-tuning"][-2].startswith("+4.10 ± 0.14") and rows["Fine-tuning"][-1] == ""
    psnr, ssim, lpips = rows["Full"][-1].split(" / ")  # paired by seed, each metric on its own
    assert rows["Full"][-2].startswith("+4.55") and psnr == "+0.45 ± 0.07 (n.s.)"
    assert ssim == "+0.0090 ± 0.0014 (n.s.)" and lpips == "–"  # no LPIPS in these results
