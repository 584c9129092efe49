"""The add-on's dependency installer, without Blender: the pins, the pip command and its outcome."""

import pathlib
import sys

from mogaface.core import dependencies

ROOT = pathlib.Path(__file__).resolve().parents[1]


def pinned_in_requirements_txt() -> dict:
    lines = (ROOT / "requirements.txt").read_text().splitlines()
    pins = [line.split("#")[0].strip() for line in lines]
    return dict(pin.split("==") for pin in pins if "==" in pin)


def test_pins_match_requirements_txt():
    pinned = pinned_in_requirements_txt()
    for requirement in dependencies.requirements():
        name, version = requirement.split("==")
        assert pinned[name] == version, requirement
    names = {r.split("==")[0] for r in dependencies.requirements()}
    assert names == set(pinned) - {"bpy", "pytest"}


def test_install_command_targets_the_folder_with_the_pins(tmp_path):
    argv = dependencies.install_command("/opt/python3", tmp_path)
    assert argv[:4] == ["/opt/python3", "-m", "pip", "install"]
    assert argv[argv.index("--target") + 1] == str(tmp_path)
    assert {"torch==2.13.0", "numpy==1.26.4", "numba==0.68.1", "OpenEXR==3.5.3"} <= set(argv)


def fake_python(folder: pathlib.Path, body: str) -> str:
    script = folder / "fake-python"
    script.write_text(f"#!{sys.executable}\nimport sys\n{body}\n")
    script.chmod(0o755)
    return str(script)


def test_install_reports_success_and_pip_errors(tmp_path):
    ok, message = dependencies.install(fake_python(tmp_path, "pass"), tmp_path / "site")
    assert ok and str(tmp_path / "site") in message
    body = "print('noise', file=sys.stderr)\nprint('ERROR: boom', file=sys.stderr)\nsys.exit(2)"
    failing = fake_python(tmp_path, body)
    ok, message = dependencies.install(failing, tmp_path / "site")
    assert not ok and message.startswith("pip failed (exit 2)") and message.endswith("ERROR: boom")


def test_install_never_hangs_and_survives_a_missing_interpreter(tmp_path):
    ok, message = dependencies.install(fake_python(tmp_path, "import time\ntime.sleep(30)"), tmp_path, timeout=0.5)
    assert not ok and "did not finish" in message
    ok, message = dependencies.install(str(tmp_path / "no-such-python"), tmp_path)
    assert not ok and "Cannot run" in message
