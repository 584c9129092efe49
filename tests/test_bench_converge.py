"""``bench converge`` (a smoke run at its quick size): the capture is made at its own non-square
size and reused, each variant trains to its time budget and is scored as it goes (the modules'
avatar for the full method), and the plot is written."""

import json
import shutil
import tomllib

import numpy as np
import pytest
from PIL import Image

from mogaface.core.cli import main

pytestmark = pytest.mark.benchmark  # a benchmark command end to end: CI's second pytest run


def test_the_curve_is_scored_as_training_goes_and_the_capture_is_reused(tmp_path, capsys):
    work = tmp_path / "work"
    out = tmp_path / "converge.json"
    assert main(["bench", "converge", "--quick", "--threads", "1", "--work", str(work), "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    capture = report["capture"]
    assert (capture["width"], capture["height"]) == (96, 66) and capture["made_in_s"] > 0
    assert capture["training_cameras"] == 3 and capture["training_images"] > 0
    for name in ("finetune", "full_prior"):
        variant = report["variants"][name]
        curve = variant["curve"]
        assert len(curve) >= 2, name
        minutes = [point["minutes"] for point in curve]
        assert minutes == sorted(minutes) and minutes[0] == 0.0
        assert [p["step"] for p in curve] == sorted({p["step"] for p in curve})  # no state scored twice
        assert minutes[-1] == variant["training_minutes"] <= report["minutes"] + 0.05  # the budget, give a step
        assert all(5 < p["psnr"] < 60 and 0 < p["ssim"] <= 1 and 0 <= p["lpips"] < 1 for p in curve)
        assert curve[-1]["psnr"] > curve[0]["psnr"]  # training helps the held-out view
    # the last point is the written run as 'eval' scores it: the modules' avatar, not the plain one
    from mogaface.core.evaluate.evaluation import evaluate_run

    run = work / "runs" / "full_prior"
    assert (run / "mogaface.pt").is_file()
    scored = evaluate_run(run, ["novel_view"], 3, lpips=False, out_dir=tmp_path / "eval")["protocols"]["novel_view"]
    assert abs(scored["psnr"] - report["variants"]["full_prior"]["curve"][-1]["psnr"]) < 0.01
    plot = np.asarray(Image.open(report["plot"]))
    assert plot.ndim == 3 and (np.abs(plot.astype(int) - [31, 119, 180]).sum(-1) < 30).any()  # a curve drawn
    capsys.readouterr()
    second = tmp_path / "again.json"
    assert main(["bench", "converge", "--quick", "--threads", "1", "--work", str(work), "--minutes", "0.02",
                 "--variants", "finetune", "--out", str(second)]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["capture"]["made_in_s"] == 0.0 and again["minutes"] == 0.02  # the capture reused
    assert list(again["variants"]) == ["finetune"]
    # a capture named by the user: trained and scored where it lies, its size read from it
    given = tmp_path / "given.json"
    assert main(["bench", "converge", "--quick", "--threads", "1", "--capture", str(work / "capture"), "--minutes",
                 "0.02", "--variants", "finetune", "--work", str(tmp_path / "other"), "--out", str(given)]) == 0
    capsys.readouterr()
    named = json.loads(given.read_text())
    assert named["capture"]["path"] == str(work / "capture") and named["capture"]["made_in_s"] == 0.0
    assert (named["capture"]["width"], named["capture"]["height"]) == (96, 66)
    assert not (tmp_path / "other" / "capture").exists() and (tmp_path / "other" / "runs" / "finetune").is_dir()
    assert len(named["variants"]["finetune"]["curve"]) >= 2
    no_val = tmp_path / "no_val"
    shutil.copytree(work / "capture", no_val)
    (no_val / "transforms_val.json").unlink()
    assert main(["bench", "converge", "--quick", "--capture", str(no_val), "--work", str(tmp_path / "other")]) == 2
    assert "no_val: field 'split': no 'val' split" in capsys.readouterr().err
    # the curves of both reports side by side, timed to the first one's final PSNR
    assert main(["bench", "converge", "--compare", f"{out},{second}", "--work", str(tmp_path / "cmp"),
                 "--out", str(tmp_path / "cmp.json")]) == 0
    compared = json.loads((tmp_path / "cmp.json").read_text())
    rows = {row["curve"]: row for row in compared["rows"]}
    assert list(rows) == ["finetune", "full_prior", "finetune (again)"] and compared["reference"] == "finetune"
    assert rows["finetune"]["delta_psnr"] == 0.0
    assert rows["finetune"]["minutes_to_reference"] <= report["variants"]["finetune"]["training_minutes"]
    assert "| finetune (again) |" in (tmp_path / "cmp.md").read_text() and (tmp_path / "cmp" / "converge.png").is_file()
    assert main(["bench", "converge", "--compare", str(tmp_path / "cmp.json")]) == 2  # not a converge report
    assert main(["bench", "train", "--minutes", "3"]) == 2
    assert main(["bench", "converge", "--minutes", "0"]) == 2


def test_a_variant_trains_on_ranks_with_one_image_each_under_a_settings_file(tmp_path):
    out, schedule = tmp_path / "ranks.json", tmp_path / "early_sh.toml"
    schedule.write_text("[densify]\nsh_degree_interval = 40\n[train]\nschedule = 'minutes'\n")  # the bench's minutes
    assert main(["bench", "converge", "--quick", "--threads", "2", "--ranks", "2", "--variants", "finetune",
                 "--config", str(schedule), "--minutes", "0.05", "--work", str(tmp_path / "work"),
                 "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["ranks"] == 2 and list(report["variants"]) == ["finetune_early_sh_2ranks"]
    settings = tomllib.loads((tmp_path / "work" / "runs" / "finetune_early_sh_2ranks" / "config.toml").read_text())
    assert settings["densify"]["sh_degree_interval"] == 20 and settings["train"]["batch"] == 2  # the file's, halved
    assert settings["train"]["schedule"] == "minutes"
    variant = report["variants"]["finetune_early_sh_2ranks"]
    assert (variant["batch"], variant["threads_per_rank"]) == (2, 1)
    assert abs(variant["images_per_s"] - 2 * variant["it_s"]) < 0.01
    curve = variant["curve"]
    assert len(curve) >= 2 and curve[0]["minutes"] == 0.0 and curve[-1]["step"] == variant["steps"] > 0
    assert main(["bench", "converge", "--quick", "--variants", "nope", "--work", str(tmp_path / "work")]) == 2


def test_minutes_to_reach_interpolates_between_scores():
    from mogaface.bench.converge import minutes_to_reach

    curve = [{"minutes": 0.0, "psnr": 15.0}, {"minutes": 5.0, "psnr": 25.0}, {"minutes": 10.0, "psnr": 24.0},
             {"minutes": 15.0, "psnr": 29.0}]
    assert minutes_to_reach(curve, 20.0) == 2.5 and minutes_to_reach(curve, 25.0) == 5.0
    assert minutes_to_reach(curve, 26.0) == 12.0  # the first crossing, after the dip
    assert minutes_to_reach(curve, 30.0) is None and minutes_to_reach(curve, 10.0) == 0.0


def test_the_measured_schedules_load_as_the_bench_gives_them():
    import pathlib

    from mogaface.bench.converge import variant_config

    folder = pathlib.Path(__file__).resolve().parents[1] / "bench" / "schedules"
    schedules = {path.stem: variant_config("finetune", 15.0, 2, 1, str(path)) for path in folder.glob("*.toml")}
    assert set(schedules) == {"budget_15", "budget_30", "budget_60", "mcmc_15"}
    assert all(c.train.schedule == "minutes" and c.train.resolution_start == 0.5 for c in schedules.values())
    assert schedules["budget_60"].train.steps == 4 * schedules["budget_15"].train.steps
    # half an hour: the default's step counts times 2, full size from the first quarter on
    half_hour, quarter = schedules["budget_30"], schedules["budget_15"]
    assert half_hour.train.steps == 2 * quarter.train.steps and half_hour.train.resolution_full == 0.25
    for name in ("start", "stop", "opacity_reset_interval", "sh_degree_interval"):
        assert getattr(half_hour.densify, name) == 2 * getattr(quarter.densify, name), name
    assert half_hour.densify.interval == quarter.densify.interval
    # the fixed budget's schedule is budget_15's but for the densification strategy and its cap
    budget, mcmc = schedules["budget_15"], schedules["mcmc_15"]
    assert (mcmc.densify.strategy, mcmc.densify.max_gaussians) == ("mcmc", 20000) and budget.densify.strategy == "adaptive"
    assert mcmc.train == budget.train and mcmc.loss == budget.loss
