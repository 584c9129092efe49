"""``--help`` of the program and of every command is answered without importing torch or numba
(parse first, import the command's work after), in a fresh interpreter as a user starts it."""

import subprocess
import sys

from mogaface.core.cli import COMMANDS

HEAVY = ("torch", "numba")

# Runs each ``--help`` in this one interpreter (argparse leaves by SystemExit) and prints, per
# call, the heavy modules imported so far. A command that ran ends the process (``exits.leave``),
# running the atexit work first: its line is printed there.
PROBE = """
import atexit, runpy, sys
def row(argv):
    print(" ".join(argv), "|", ",".join(m for m in {heavy!r} if m in sys.modules), file=sys.stderr)
for argv in {calls!r}:
    sys.argv = ["mogaface", *argv]
    atexit.register(row, argv)
    try:
        runpy.run_module("mogaface", run_name="__main__", alter_sys=True)
    except SystemExit as leaving:
        assert leaving.code in (0, None), (argv, leaving.code)
    atexit.unregister(row)
    row(argv)
"""


def _heavy_after(calls: list[list[str]]) -> dict[str, str]:
    done = subprocess.run([sys.executable, "-c", PROBE.format(calls=calls, heavy=HEAVY)], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rows = [line.split(" | ") for line in done.stderr.splitlines() if " | " in line]
    assert len(rows) == len(calls), done.stderr
    return dict(rows)


def test_help_imports_neither_torch_nor_numba():
    calls = [["--help"], *([name, "--help"] for name in COMMANDS)]
    heavy = _heavy_after(calls)
    assert heavy == {" ".join(call): "" for call in calls}


def test_the_probe_sees_an_import_of_torch():
    """Negative control: a command that runs does import them, and the probe reports it."""
    heavy = _heavy_after([["--help"], ["environment"]])
    assert heavy["--help"] == "" and set(heavy["environment"].split(",")) == set(HEAVY)


def test_help_of_the_program_through_python_dash_m():
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "mogaface", "eval", "--help"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "--protocols" in done.stdout
    imported = {line.rsplit("|", 1)[-1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")}
    assert "mogaface.core.evaluate.protocol_names" in imported  # eval's arguments were built (its choices)
    assert not imported & set(HEAVY), sorted(imported & set(HEAVY))
