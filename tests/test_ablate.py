"""``ablate``: the ladder on a tiny capture with tiny settings writes results.json, the table and the figure."""

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
    code = main(["ablate", str(tiny_capture), "--out", str(out), "--config", str(settings), "--steps", "3",
                 "--max-frames", "2", "--no-lpips", "--quiet"])
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    assert list(results["variants"]) == ["freeze", "finetune", "single", "multi", "multi_bank", "multi_texture", "full",
                                         "full_prior"]
    for name, entry in results["variants"].items():
        for key in ("novel_view", "self_reenactment_params", "self_reenactment_images"):
            assert entry[key]["frames"] == 2 and entry[key]["psnr"] > 5, (name, key)
        assert entry["expression"]["expr_rmse_tracked"] > 0
        assert entry["train"]["steps"] == 3
    freeze = results["variants"]["freeze"]["expression"]
    assert freeze["expr_rmse_corrected"] == pytest.approx(freeze["expr_rmse_tracked"])  # Freeze corrects nothing
    assert freeze["expr_vertex_mm_corrected"] == pytest.approx(freeze["expr_vertex_mm_tracked"])
    finetune = results["variants"]["finetune"]
    assert finetune["settings"]["flame"]["finetune"] and not results["variants"]["freeze"]["settings"]["flame"]["finetune"]
    assert finetune["expression"]["expr_rmse_corrected"] != pytest.approx(finetune["expression"]["expr_rmse_tracked"])
    table = (out / "results.md").read_text()
    prior = [results["variants"][name]["settings"]["mogaface"]["centring_weight"] for name in ("full", "full_prior")]
    assert prior[0] == 0 and prior[1] > 0
    assert table.count("\n") == 2 + 8 and "Full (multi + bank + texture)" in table
    assert (out / "figure.png").stat().st_size > 0
    # A second call reuses the complete runs.
    before = (out / "runs" / "full" / "run.json").stat().st_mtime_ns
    assert main(["ablate", str(tiny_capture), "--out", str(out), "--config", str(settings), "--steps", "3",
                 "--variants", "full", "--max-frames", "2", "--no-lpips", "--quiet"]) == 0
    assert (out / "runs" / "full" / "run.json").stat().st_mtime_ns == before
