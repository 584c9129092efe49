"""A training run in a separate process, and the one reader of its progress.

Blender must never block on training, and torch may live in another interpreter than
Blender's. :class:`TrainWorker` starts ``python -m mogaface train …`` as a child process
(:func:`worker_command`: isolated, with exactly the package folders it is given),
reads new lines of ``RUN/events.jsonl`` incrementally (:meth:`TrainWorker.poll`), knows when the
child ended and why (exit code, the tail of its stderr), and cancels it with SIGINT (the trainer
then writes a checkpoint). The UI calls :meth:`~TrainWorker.poll` from a timer; headless code
calls :meth:`~TrainWorker.wait`, which is the same poll in a loop. :class:`RefineTrackingWorker`
is the same for ``python -m mogaface refine-tracking RUN`` (its own events file and messages).
No Blender here.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time

from ..errors import InputError
from ..run import names as run_names

#: The package's import name; the child runs ``python -m mogaface train``.
PACKAGE = "mogaface"


@dataclasses.dataclass
class Progress:
    """What the UI shows: where the run is and how it is doing."""

    state: str = "starting"  # starting, running, done, cancelled, failed
    stage: str | None = None  # a job of several stages names the one running
    step: int = 0
    steps: int = 0
    loss: float | None = None
    psnr: float | None = None
    eta_s: float | None = None
    val_psnr: float | None = None
    message: str = ""
    warnings: list[str] = dataclasses.field(default_factory=list)  # what the run said it could not do

    @property
    def fraction(self) -> float:
        return min(1.0, self.step / self.steps) if self.steps else 0.0

    @property
    def finished(self) -> bool:
        return self.state in ("done", "cancelled", "failed")

    def text(self) -> str:
        """One line: step, loss, PSNR, ETA (the status bar and the logs)."""
        return ", ".join(part for part in (self.bar_text().replace(" · ", ", "), self.detail_text()) if part)

    def bar_text(self) -> str:
        """Short enough for a progress bar in the sidebar at its default width: where the run is and
        how long it has left ("compiling" until the first steps are timed)."""
        where = f"{self.stage or 'step'} {self.step}/{self.steps}" if self.steps else self.state
        if self.state != "running":
            return where
        if self.eta_s is not None:
            return f"{where} · ETA {format_seconds(self.eta_s)}"
        return f"{where} · {'compiling' if self.loss is None else 'timing'}"

    def detail_text(self) -> str:
        """The numbers the bar leaves out: the loss and the training PSNR."""
        parts = []
        if self.loss is not None:
            parts.append(f"loss {self.loss:.4f}")
        if self.psnr is not None:
            parts.append(f"PSNR {self.psnr:.2f} dB")
        return ", ".join(parts)


def format_seconds(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    return f"{seconds // 60}:{seconds % 60:02d}"


#: Loads the package from one explicit folder under its plain name, then runs its ``__main__``.
#: With ``-I`` nothing comes from the working directory, ``PYTHONPATH`` or the user's site folder.
_BOOTSTRAP = """\
import importlib.util, json, runpy, sys
spec = json.loads(sys.argv.pop(1))
sys.path[:0] = spec["path"]
found = importlib.util.spec_from_file_location(
    spec["name"], spec["init"], submodule_search_locations=[spec["root"]])
module = importlib.util.module_from_spec(found)
sys.modules[spec["name"]] = module
found.loader.exec_module(module)
runpy.run_module(spec["name"], run_name="__main__", alter_sys=True)
"""


def package_root() -> pathlib.Path:
    """The folder of this package (an installed extension's folder, or the checkout)."""
    return pathlib.Path(__file__).resolve().parents[2]


def worker_command(python: str | None, arguments, paths=()) -> list[str]:
    """argv of ``python -m mogaface ARGUMENTS`` that can import only the intended code.

    The child runs isolated (``-I``): no working directory, ``PYTHONPATH`` or user site folder on
    its path. It imports this very package folder as ``mogaface`` (whatever the folder is called,
    and nothing else beside it), with ``paths`` (the folders that hold the packages the extension
    installed) in front of the interpreter's own ``sys.path``.
    """
    root = package_root()
    spec = {"name": PACKAGE, "root": os.fspath(root), "init": os.fspath(root / "__init__.py"),
            "path": [os.fspath(path) for path in paths]}
    return [python or sys.executable, "-I", "-u", "-c", _BOOTSTRAP, json.dumps(spec), *map(str, arguments)]


def module_arguments(command: list[str]) -> list[str]:
    """``["-m", "mogaface", ARGUMENTS…]`` of a :func:`worker_command` (or of a plain ``-m`` command)."""
    if "-c" in command and command[command.index("-c") + 1] == _BOOTSTRAP:
        return ["-m", PACKAGE, *command[command.index("-c") + 3:]]
    if "-m" in command:
        return command[command.index("-m"):]
    raise InputError(None, "command", "not a 'python -m mogaface' worker command")


def worker_environment(base: dict | None = None) -> dict:
    """The child's environment: the parent's, less what would change which code it loads.

    ``-I`` already ignores ``PYTHON*`` variables; ``NUMBA_CACHE_DIR`` is dropped so the child
    picks the cache folder of its own import name (core/numba_cache.py).
    """
    env = dict(os.environ if base is None else base)
    for name in [key for key in env if key.startswith("PYTHON")] + ["NUMBA_CACHE_DIR"]:
        env.pop(name, None)
    return env


def train_command(python: str, capture, run, preset: str | None = None, steps: int | None = None,
                  seed: int | None = None, threads: int | None = None, resume: bool = False,
                  camera_rounds: int = 0, cameras_from_landmarks: bool = False, centres_measured: bool = False,
                  camera_delays: bool = False, minutes: float = 0.0, extra: list[str] | None = None,
                  paths=()) -> list[str]:
    """The argument list of a training child process (see :func:`worker_command` for ``paths``);
    ``camera_rounds`` > 0 refines the cameras in that many rounds, from cameras solved from the
    capture's landmarks with ``cameras_from_landmarks``, turning them about centres that hold the
    rig with ``centres_measured`` (gauge none); ``camera_delays`` learns each camera's time offset
    (unsynchronised cameras); ``minutes`` > 0 runs the schedule through that much training time
    (``train --minutes``). A resumed run keeps its own settings."""
    arguments = ["train", os.fspath(capture), "--out", os.fspath(run), "--quiet"]
    if resume:
        arguments.append("--resume")
    else:
        arguments += ["--preset", preset] if preset else []
        arguments += ["--refine-cameras", str(int(camera_rounds))] if camera_rounds > 0 else []
        arguments += ["--cameras-start", "landmarks"] if camera_rounds > 0 and cameras_from_landmarks else []
        arguments += ["--camera-gauge", "none"] if camera_rounds > 0 and centres_measured else []
        arguments += ["--camera-delays"] if camera_delays else []
        arguments += ["--minutes", f"{float(minutes):g}"] if minutes > 0 else []
    for flag, value in (("--steps", steps), ("--seed", seed), ("--threads", threads)):
        if value is not None:
            arguments += [flag, str(int(value))]
    return worker_command(python, arguments + list(extra or []), paths)


class EventReader:
    """Reads the complete lines appended to a JSON-lines file since the last call."""

    def __init__(self, path):
        self.path = pathlib.Path(path)
        self.offset = 0
        self._partial = b""

    def read(self) -> list[dict]:
        try:
            with open(self.path, "rb") as handle:
                handle.seek(self.offset)
                data = handle.read()
        except FileNotFoundError:
            return []
        self.offset += len(data)
        data = self._partial + data
        lines = data.split(b"\n")
        self._partial = lines.pop()  # an incomplete last line waits for the next read
        events = []
        for line in lines:
            try:
                event = json.loads(line)
            except ValueError:
                continue
            if isinstance(event, dict):
                events.append(event)
        return events


class TrainWorker:
    """One training child process and its progress.

    ``command``: the child's argument list (see :func:`train_command`); ``run``: its run folder,
    whose ``events.jsonl`` is read. Events written before the start (a resumed run) are skipped.
    """

    EVENTS_FILE = run_names.EVENTS_FILE
    JOB = "training"
    CANCELLED = "checkpoint written"  # what a cancelled job leaves
    DONE = "finished at step {step}"

    def __init__(self, command: list[str], run, env: dict | None = None, stderr_lines: int = 40):
        self.command = list(command)
        self.run = pathlib.Path(run)
        self.progress = Progress()
        self.events: list[dict] = []
        self._env = env
        self._stderr = collections.deque(maxlen=stderr_lines)
        self._process: subprocess.Popen | None = None
        self._reader: EventReader | None = None
        self._cancelled = False

    # -- life cycle --------------------------------------------------------------------------
    def start(self) -> "TrainWorker":
        """Start the child; an interpreter that cannot be started raises ``OSError``."""
        events = self.run / self.EVENTS_FILE
        self._reader = EventReader(events)
        self._reader.offset = events.stat().st_size if events.exists() else 0
        self.run.mkdir(parents=True, exist_ok=True)
        self._process = subprocess.Popen(
            self.command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            env=worker_environment(self._env), cwd=self.run, start_new_session=True,
        )
        threading.Thread(target=self._drain_stderr, daemon=True).start()
        self.progress.state = "running"
        return self

    def _drain_stderr(self) -> None:
        for raw in self._process.stderr:
            line = raw.decode("utf-8", "replace").rstrip()
            if line:
                self._stderr.append(line)

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    def stderr_tail(self) -> str:
        return "\n".join(self._stderr)

    def cancel(self, sig: int = signal.SIGINT) -> None:
        """Ask the child to stop; the trainer writes a checkpoint, then exits."""
        if self._process is not None and self._process.poll() is None:
            self._cancelled = True
            self._process.send_signal(sig)

    def kill(self) -> None:
        """Stop the child at once (no checkpoint): for a child that ignores :meth:`cancel`."""
        if self._process is not None and self._process.poll() is None:
            self._process.kill()
            self._process.wait()

    # -- progress ----------------------------------------------------------------------------
    def poll(self) -> Progress:
        """Read new events, check the child; returns the updated :class:`Progress` (never blocks)."""
        if self._process is None:
            return self.progress
        code = self._process.poll()
        for event in self._reader.read():
            self._apply(event)
        if code is not None and not self.progress.finished:
            time.sleep(0.05)  # let the stderr thread catch the last lines
            for event in self._reader.read():
                self._apply(event)
            self._finish(code)
        return self.progress

    def _apply(self, event: dict) -> None:
        self.events.append(event)
        p, kind = self.progress, event.get("event")
        if "step" in event:  # a job of stages names each one; training's own events name none
            p.stage = event.get("stage")
        p.step = int(event.get("step", p.step) or 0)
        p.steps = int(event.get("steps", p.steps) or 0)
        if kind == "iter":
            p.loss, p.psnr, p.eta_s = event.get("loss"), event.get("psnr"), event.get("eta_s")
        elif kind == "val":
            p.val_psnr = event.get("psnr")
        elif kind == "warning" and event.get("message"):
            p.warnings.append(str(event["message"]))
        elif kind == "done":
            p.eta_s = 0.0
            metrics = event.get("metrics") or {}
            p.val_psnr = metrics.get("psnr", p.val_psnr)

    def _finish(self, code: int) -> None:
        p = self.progress
        kinds = {e.get("event") for e in self.events}
        if code == 0 and "done" in kinds:
            p.state, p.message = "done", "; ".join([self.DONE.format(step=p.step), *p.warnings])
        elif self._cancelled and ("stopped" in kinds or code in (128 + signal.SIGINT, 128 + signal.SIGTERM)):
            p.state, p.message = "cancelled", f"cancelled at {p.stage or 'step'} {p.step} ({self.CANCELLED})"
        else:
            p.state = "failed"
            tail = [line for line in self._stderr if line.strip()]
            detail = next((line for line in reversed(tail) if "error" in line.lower()), tail[-1] if tail else "")
            p.message = f"{self.JOB} failed (exit code {code})" + (f": {detail}" if detail else "")

    def wait(self, interval: float = 0.5, on_progress=None, timeout: float | None = None) -> Progress:
        """Poll until the child ends (headless use: timers never run there).

        ``on_progress(progress)`` is called after each poll that saw new events; on
        KeyboardInterrupt the child is cancelled and waited for, so its checkpoint is written.
        """
        start, seen = time.monotonic(), -1
        try:
            while True:
                progress = self.poll()
                if on_progress is not None and len(self.events) != seen:
                    seen = len(self.events)
                    on_progress(progress)
                if progress.finished:
                    return progress
                if timeout is not None and time.monotonic() - start > timeout:
                    self.cancel()
                    timeout = None
                time.sleep(interval)
        except KeyboardInterrupt:
            self.cancel()
            self._process.wait()
            return self.poll()


class RefineTrackingWorker(TrainWorker):
    """``refine-tracking RUN`` in a child process (:func:`refine_tracking_command`); a cancelled
    one replaces nothing."""

    EVENTS_FILE = run_names.REFINE_TRACKING_EVENTS_FILE
    JOB = "improving the tracking"
    CANCELLED = "nothing replaced"
    DONE = "refined {step} timesteps"


def refine_tracking_command(python: str, run, out=None, passes: int | None = None, views: int | None = None,
                            fit_steps: int | None = None, threads: int | None = None, paths=()) -> list[str]:
    """The argument list of a ``refine-tracking`` child process (see :func:`worker_command`)."""
    arguments = ["refine-tracking", os.fspath(run), "--quiet"]
    if out is not None:
        arguments += ["--out", os.fspath(out)]
    for flag, value in (("--passes", passes), ("--views", views), ("--fit-steps", fit_steps), ("--threads", threads)):
        if value is not None:
            arguments += [flag, str(int(value))]
    return worker_command(python, arguments, paths)


class FootageWorker(TrainWorker):
    """``track`` or ``drive`` in a child process (:func:`track_command`, :func:`drive_command`),
    followed through the ``--events`` file in its job folder; a cancelled track keeps its
    detections (the same command resumes it), a cancelled drive writes nothing."""

    EVENTS_FILE = "events.jsonl"
    JOB = "tracking the footage"
    CANCELLED = "nothing imported"
    DONE = "done"


def _footage_options(size, fit_steps, photometric_steps, threads) -> list[str]:
    arguments = []
    for flag, value in (("--size", size), ("--fit-steps", fit_steps), ("--photometric-steps", photometric_steps),
                        ("--threads", threads)):
        if value is not None:
            arguments += [flag, str(int(value))]
    return arguments


def track_command(python: str, inputs, out, job, size: int | None = None, fit_steps: int | None = None,
                  threads: int | None = None, paths=(), photometric_steps: int | None = None) -> list[str]:
    """The argument list of a ``track`` child process writing its events into the folder ``job``."""
    arguments = ["track", *map(os.fspath, inputs), "--out", os.fspath(out), "--quiet",
                 "--events", os.fspath(pathlib.Path(job) / FootageWorker.EVENTS_FILE)]
    return worker_command(python, arguments + _footage_options(size, fit_steps, photometric_steps, threads), paths)


def drive_command(python: str, clip, avatar, out, job, head=None, fps: float | None = None,
                  keep_head_still: bool = False, tolerance: float = 0.0, size: int | None = None,
                  fit_steps: int | None = None, threads: int | None = None, paths=(),
                  photometric_steps: int | None = None) -> list[str]:
    """The argument list of a ``drive`` child process writing its events into the folder ``job``."""
    arguments = ["drive", os.fspath(clip), "--avatar", os.fspath(avatar), "--out", os.fspath(out), "--quiet",
                 "--events", os.fspath(pathlib.Path(job) / FootageWorker.EVENTS_FILE),
                 "--tolerance", f"{float(tolerance):g}"]
    arguments += ["--head", os.fspath(head)] if head is not None else []
    arguments += ["--to-fps", f"{float(fps):.6g}"] if fps else []
    arguments += ["--keep-head-still"] if keep_head_still else []
    return worker_command(python, arguments + _footage_options(size, fit_steps, photometric_steps, threads), paths)
