"""``bench cycles`` (a smoke run at 64²): every figure is there, and the denoiser's prefilter reaches
the renderer (the same seed rendered with each gives another image)."""

import json

import numpy as np
import pytest

from mogaface.core.cli import main

pytestmark = pytest.mark.benchmark  # a benchmark command end to end: CI's second pytest run


def test_the_speed_noise_and_denoising_figures_are_measured(tmp_path, capsys):
    out = tmp_path / "cycles.json"
    assert main(["bench", "cycles", "--quick", "--threads", "2", "--out", str(out)]) == 0
    capsys.readouterr()
    report = json.loads(out.read_text())
    speed = report["speed"]["64x64"]
    assert speed["images"] == 4 and 0 < speed["seconds_per_image"] < speed["child_total_s"]
    assert set(report["real_scale_fewer_samples"]) == {"8", "16"}
    for samples, noise in report["noise"].items():
        assert 15 < noise["psnr_vs_reference_db"] < 80 and np.isfinite(noise["psnr_between_two_seeds_db"]), samples
    denoising = report["denoising"]
    assert report["denoising_at"] == "64x64" and set(denoising) == {"16_FAST", "16_ACCURATE", "32_FAST", "32_ACCURATE"}
    assert all(row["seconds_per_image"] > 0 and 15 < row["psnr_vs_reference_db"] < 80 for row in denoising.values())
    for samples in (16, 32):  # one seed, two prefilters: two images, or the setting never reached Cycles
        assert denoising[f"{samples}_FAST"]["psnr_vs_reference_db"] != denoising[f"{samples}_ACCURATE"]["psnr_vs_reference_db"]
