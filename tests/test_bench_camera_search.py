"""``bench camera_search`` (a smoke run at its quick size): a run trained per setting tried on a
capture whose cameras are off, scored on the validation frames only, its camera error beside the
score; a second search trains nothing again; the test table trains today's and the chosen settings
on a subject the search never saw and scores its test frames."""

import json
import pathlib

import pytest

from mogaface.core.cli import main


@pytest.fixture(scope="module")
def searched(tmp_path_factory):
    """The quick search's work folder and its report (the test table reuses its runs)."""
    root = tmp_path_factory.mktemp("camera_search")
    work, out = root / "work", root / "search.json"
    assert main(["bench", "camera_search", "--quick", "--threads", "1", "--work", str(work), "--out", str(out)]) == 0
    return work, json.loads(out.read_text())


def test_each_setting_trains_once_and_is_scored_on_validation_frames(searched, capsys):
    work, report = searched
    tried = report["tried"]
    assert tried[0]["settings"] == report["start"]
    assert sorted(t["settings"]["rotation_lr"] for t in tried) == [1e-3, 2e-3]  # the quick grid, each once
    for entry in tried:
        run = entry["run"]
        assert json.loads(open(f"{run}/run.json").read())["complete"]
        scores = json.loads(open(f"{run}/ablation_scores_validation.json").read())["scores"]
        assert scores["split"] == "validation" and list(scores["protocols"]) == ["self_reenactment"]
        assert abs(scores["protocols"]["self_reenactment"]["tracked"]["psnr"] - entry["psnr_db"]) < 1e-3
        assert 5 < entry["psnr_db"] < 60
        assert 0 <= entry["rotation_deg"] < 10 and entry["calibrated_rotation_deg"] > 0.5  # the capture's 1° per axis
    best = max(t["psnr_db"] for t in tried)
    assert report["chosen"] in [t["settings"] for t in tried]
    assert report["chosen_psnr_db"] == best or best - report["chosen_psnr_db"] <= 0.05  # a new value needs the margin

    stamps = {t["run"]: (work / t["run"] / "events.jsonl").stat().st_mtime_ns for t in tried}
    capsys.readouterr()
    assert main(["bench", "camera_search", "--quick", "--threads", "1", "--work", str(work)]) == 0
    again = json.loads(capsys.readouterr().out)
    assert [t["psnr_db"] for t in again["tried"]] == [t["psnr_db"] for t in tried]
    assert {t["run"]: (work / t["run"] / "events.jsonl").stat().st_mtime_ns for t in tried} == stamps

    assert main(["bench", "camera_search", "--quick", "--work", str(work), "--split", "test"]) == 2
    assert "validation frames only" in capsys.readouterr().err
    assert main(["bench", "camera_search", "--quick", "--work", str(work), "--test-subjects", "0,1"]) == 2
    assert "search's own" in capsys.readouterr().err


def test_the_test_table_scores_today_and_the_chosen_settings_on_an_unseen_subject(searched, capsys):
    work, searched_report = searched
    assert main(["bench", "camera_search", "--quick", "--threads", "1", "--work", str(work), "--test-subjects", "1"]) == 0
    report = json.loads(capsys.readouterr().out)
    table = report["test"]
    assert table["split"] == "test" and [(r["subject"], r["settings"]) for r in table["rows"]] == [
        (1, "today"), (1, "chosen")]
    info = json.loads((work / "test_capture_s1" / "capture_info.json").read_text())["settings"]
    assert info["subject"] == 1 and info["seed"] == 1 and info["camera_noise"] == 1.0  # its own draw
    for row in table["rows"]:
        settings = {k: row[k] for k in report["start"]}
        assert settings == (report["start"] if row["settings"] == "today" else report["chosen"])
        assert pathlib.Path(row["run"]).parent == work / "test_runs_s1"
        scores = json.loads((pathlib.Path(row["run"]) / "ablation_scores.json").read_text())["scores"]
        assert scores["split"] == "test"
        assert abs(scores["protocols"]["novel_view"]["tracked"]["psnr"] - row["novel_view_psnr_db"]) < 1e-3
        assert row["scored_frames"]["novel_view"] > 0 and row["scored_frames"]["self_reenactment"] > 0
    assert report["tried"] == searched_report["tried"]  # the search's runs reused, not trained again
    rows = {r["settings"]: r for r in table["rows"]}
    gain = table["chosen_minus_today"]["novel_view_psnr_db"]
    assert gain["n"] == 1 and gain["beyond_noise"] is None  # one subject can never tell
    assert abs(gain["mean"] - (rows["chosen"]["novel_view_psnr_db"] - rows["today"]["novel_view_psnr_db"])) < 1e-9

