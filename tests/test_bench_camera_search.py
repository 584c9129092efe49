"""``bench camera_search`` (a smoke run at its quick size): a run trained per setting tried and
subject searched on, on captures whose cameras are off, scored on the validation frames only and
chosen on their mean, its camera error beside the score; a second search trains nothing again; the
test table trains today's and the chosen settings on a subject the search never saw and scores its
test frames."""

import json
import pathlib

import pytest

from mogaface.core.cli import main

pytestmark = pytest.mark.benchmark  # a benchmark command end to end: CI's second pytest run


@pytest.fixture(scope="module")
def searched(tmp_path_factory):
    """The quick search's work folder and its report (the test table reuses its runs)."""
    root = tmp_path_factory.mktemp("camera_search")
    work, out = root / "work", root / "search.json"
    assert main(["bench", "camera_search", "--quick", "--threads", "1", "--work", str(work), "--out", str(out),
                 "--subjects", "0,2"]) == 0
    return work, json.loads(out.read_text())


def test_each_setting_trains_once_and_is_scored_on_validation_frames(searched, capsys):
    work, report = searched
    tried = report["tried"]
    assert tried[0]["settings"] == report["start"]
    assert sorted(t["settings"]["rotation_lr"] for t in tried) == [1e-3, 2e-3]  # the quick grid, each once
    assert report["subjects"] == [0, 2]
    for entry in tried:
        assert [t["subject"] for t in entry["subjects"]] == [0, 2]
        assert abs(entry["psnr_db"] - sum(t["psnr_db"] for t in entry["subjects"]) / 2) < 1e-3  # chosen on the mean
        for subject in entry["subjects"]:
            run = subject["run"]
            assert pathlib.Path(run).parent == work / ("runs_quick" if subject["subject"] == 0 else "runs_s2_quick")
            assert json.loads(open(f"{run}/run.json").read())["complete"]
            scores = json.loads(open(f"{run}/ablation_scores_validation.json").read())["scores"]
            assert scores["split"] == "validation" and list(scores["protocols"]) == ["self_reenactment"]
            assert abs(scores["protocols"]["self_reenactment"]["tracked"]["psnr"] - subject["psnr_db"]) < 1e-3
            assert 5 < subject["psnr_db"] < 60
            assert 0 <= subject["rotation_deg"] < 10 and subject["calibrated_rotation_deg"] > 0.5  # 1° per axis
    info = json.loads((work / "capture_s2_quick" / "capture_info.json").read_text())["settings"]
    assert info["subject"] == 2 and info["seed"] == 2 and info["camera_noise"] == 1.0  # its own draw
    assert entry["subjects"][0]["psnr_db"] != entry["subjects"][1]["psnr_db"]
    best = max(t["psnr_db"] for t in tried)
    assert report["chosen"] in [t["settings"] for t in tried]
    assert report["chosen_psnr_db"] == best or best - report["chosen_psnr_db"] <= 0.05  # a new value needs the margin

    def stamps():
        return {s["run"]: pathlib.Path(s["run"], "events.jsonl").stat().st_mtime_ns for t in tried for s in t["subjects"]}

    before = stamps()
    capsys.readouterr()
    assert main(["bench", "camera_search", "--quick", "--threads", "1", "--work", str(work), "--subjects", "0,2"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert [t["psnr_db"] for t in again["tried"]] == [t["psnr_db"] for t in tried]
    assert stamps() == before

    assert main(["bench", "camera_search", "--quick", "--work", str(work), "--split", "test"]) == 2
    assert "validation frames only" in capsys.readouterr().err
    assert main(["bench", "camera_search", "--quick", "--work", str(work), "--subjects", "0,2",
                 "--test-subjects", "1,2"]) == 2
    assert "no choice was made on" in capsys.readouterr().err


def test_the_test_table_scores_today_and_the_chosen_settings_on_an_unseen_subject(searched, capsys):
    work, searched_report = searched
    assert main(["bench", "camera_search", "--quick", "--threads", "1", "--work", str(work), "--subjects", "0,2",
                 "--test-subjects", "1"]) == 0
    report = json.loads(capsys.readouterr().out)
    table = report["test"]
    assert table["split"] == "test" and [(r["subject"], r["settings"]) for r in table["rows"]] == [
        (1, "today"), (1, "chosen")]
    for row in table["rows"]:
        settings = {k: row[k] for k in report["start"]}
        assert settings == (report["start"] if row["settings"] == "today" else report["chosen"])
        assert pathlib.Path(row["run"]).parent == work / "runs_s1_quick"
        scores = json.loads((pathlib.Path(row["run"]) / "ablation_scores.json").read_text())["scores"]
        assert scores["split"] == "test"
        assert abs(scores["protocols"]["novel_view"]["tracked"]["psnr"] - row["novel_view_psnr_db"]) < 1e-3
        assert row["scored_frames"]["novel_view"] > 0 and row["scored_frames"]["self_reenactment"] > 0
    assert report["tried"] == searched_report["tried"]  # the search's runs reused, not trained again
    rows = {r["settings"]: r for r in table["rows"]}
    gain = table["chosen_minus_today"]["novel_view_psnr_db"]
    assert gain["n"] == 1 and gain["beyond_noise"] is None  # one subject can never tell
    assert abs(gain["mean"] - (rows["chosen"]["novel_view_psnr_db"] - rows["today"]["novel_view_psnr_db"])) < 1e-9

