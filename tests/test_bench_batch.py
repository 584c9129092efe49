"""``bench batch`` (a smoke run at its quick size): every batch sees the same images in fewer
steps, every row is scored at the held-out camera, and a second run reuses the runs it finds."""

import json

import pytest

from mogaface.core.cli import main

pytestmark = pytest.mark.benchmark  # a benchmark command end to end: CI's second pytest run


def test_each_batch_sees_the_same_images_and_runs_are_reused(tmp_path):
    work, out = tmp_path / "work", tmp_path / "batch.json"
    assert main(["bench", "batch", "--quick", "--threads", "1", "--work", str(work), "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    rows = {(row["batch"], row["rule"]): row for row in report["rows"]}
    assert set(rows) == {(1, "none"), (4, "sqrt"), (4, "none")}
    assert all(row["steps"] * batch == report["images"] for (batch, _), row in rows.items())
    assert all(5 < row["psnr"][0] < 60 and 0 < row["lpips"][0] < 1 for row in rows.values())
    assert rows[(1, "none")]["delta_psnr"]["mean"] == 0.0
    assert "| 4 | sqrt | 12 |" in out.with_suffix(".md").read_text()
    trained = {path: path.stat().st_mtime_ns for path in work.glob("runs/*/run.json")}
    assert len(trained) == 3
    assert main(["bench", "batch", "--quick", "--threads", "1", "--work", str(work), "--out", str(out)]) == 0
    assert {path: path.stat().st_mtime_ns for path in work.glob("runs/*/run.json")} == trained
    assert json.loads(out.read_text())["rows"] == report["rows"]
