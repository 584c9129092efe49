"""The demo command end to end, shrunk with ``--tiny`` (a child process, well under a minute)."""

import json
import subprocess
import sys


def test_tiny_demo_leaves_every_output(tmp_path):
    out = tmp_path / "demo"
    result = subprocess.run([sys.executable, "-m", "mogaface", "demo", "--tiny", "--out", str(out)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    for name in ("demo.blend", "metrics.json", "metrics.md", "report.md", "cross_identity.gif",
                 "avatar_world_t00000.ply", "frames_strip.png", "timings.json", "run/avatar.pt",
                 "eval/cross_identity/strip.png", "preview/contact_sheet.png"):
        assert (out / name).exists(), name
    assert len(list((out / "frames").glob("*.png"))) == 3
    metrics = json.loads((out / "metrics.json").read_text())
    assert {"novel_view", "self_reenactment"} <= set(metrics["protocols"]) and metrics["cross_identity"]["frames"]
    report = (out / "report.md").read_text()
    assert "| novel view |" in report and "![" in report and "| **total** |" in report
    for line in report.splitlines():  # every image the report shows exists
        if line.startswith("!["):
            assert (out / line.split("](")[1].rstrip(")")).exists(), line
    assert "[demo] done in" in result.stdout
