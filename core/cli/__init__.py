"""The ``python -m mogaface`` command line.

Each sub-command is a module in this package with ``add_arguments(parser)`` and
``run(args) -> int``. Arguments are parsed first and torch and numba imported after, and only
the named command's module is imported (its ``add_arguments`` imports nothing heavy), so
``--help`` and a usage error stay fast and load neither torch nor numba
(tests/test_cli_light.py).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import signal
import sys
import threading

from ..errors import MogafaceError
from . import exits

# a full or read-only disk, or a folder the user may not write: a clear error, not a traceback
_DISK_ERRORS = {errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, getattr(errno, "EDQUOT", errno.ENOSPC)}

# name -> (module in this package, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "make-head": ("make_head", "write the procedural default head model (FLAME file layout)"),
    "preview-head": ("preview_head", "render preview images of a head model"),
    "make-capture": ("make_capture", "render a synthetic multi-view capture of the procedural head"),
    "make-footage": ("make_footage", "render synthetic phone footage (a clip or photos) of the procedural head, "
                                     "its truth aside"),
    "track": ("track", "turn a phone video (or several) or a folder of photos into a tracked capture (CPU, offline)"),
    "drive": ("drive", "a performance clip drives an avatar: track it with the avatar's shape held fixed, write "
                       "its frames as flame_param files"),
    "check-capture": ("check_capture", "validate a capture folder and print a summary"),
    "eval": ("eval", "score a trained run on the evaluation protocols (metrics.json, metrics.md)"),
    "render": ("render", "render a trained run's avatar at chosen timesteps and cameras (PNG, EXR)"),
    "export-ply": ("export_ply", "export a run's avatar as a Gaussian PLY (world or binding space)"),
    "import-ply": ("import_ply", "turn a binding-space Gaussian PLY back into an avatar file"),
    "demo": ("demo", "run the main job on the embedded default head"),
    "train": ("train", "train an avatar on a capture (resumable run folder)"),
    "bench": ("bench", "run a benchmark and print JSON"),
    "environment": ("environment", "print where this process finds its code and packages (JSON)"),
    "compile-kernels": ("compile_kernels", "compile the engine's numba kernels into the user's cache now, so the "
                                           "first render or training starts at full pace (JSON)"),
    "train-refiner": ("train_refiner", "train the multi-view refiner of per-frame parameters on a finished run"),
    "refine-tracking": ("refine_tracking", "improve a capture's tracking with a run's refiner; write flame_param files"),
    "solve-cameras": ("solve_cameras", "turn a capture's cameras to fit its 2D landmarks; write a cameras file"),
    "ablate": ("ablate", "train and score the MoGaFace ablation ladder on one capture (results.json, results.md)"),
}


def step_counts(text: str) -> tuple[int, ...]:
    """An argparse type: ``"10,30"`` → ``(10, 30)``, positive counts only (the fitting lengths of
    ``ablate`` and ``bench refiner``)."""
    try:
        counts = tuple(int(part) for part in text.split(","))
    except ValueError:
        counts = ()
    if not counts or min(counts) < 1:
        raise argparse.ArgumentTypeError(f"expected positive step counts separated by commas, got {text!r}")
    return counts


def add_split_argument(parser) -> None:
    """``--split``: which unseen frames ``eval``, ``ablate`` and ``bench refiner`` score."""
    from ..evaluate.protocol_names import SCORE_SPLITS

    parser.add_argument("--split", choices=SCORE_SPLITS, default="test",
                        help="the test frames (the held-out sequence, default) or the validation sequence's "
                             "(self-reenactment only): choose settings on validation, score test once")


def _build_parser(argv: list[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m mogaface",
        description="MoGaFace: animatable Gaussian head avatars from multi-view captures.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    wanted = next((a for a in argv if not a.startswith("-")), None)
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == wanted:
            _command_module(name).add_arguments(p)
    return parser


def _command_module(name: str):
    return importlib.import_module(f"{__name__}.{COMMANDS[name][0]}")


def _load_heavy_modules_uninterrupted() -> bool:
    """Import torch and numba with Ctrl-C held back; True if one came meanwhile.

    A KeyboardInterrupt raised inside torch's C++ start-up aborts the process (``terminate
    called after throwing ... KeyboardInterrupt``); raised anywhere else in start-up it is an
    ordinary exception. So the interrupt is only noted there and acted on afterwards.
    """
    if threading.current_thread() is not threading.main_thread():
        import numba  # noqa: F401
        import torch  # noqa: F401
        return False
    noted = []
    previous = {number: signal.signal(number, lambda number, frame: noted.append(number))
                for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        import numba  # noqa: F401
        import torch  # noqa: F401
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
    if signal.SIGTERM in noted:
        raise exits.Terminated(signal.SIGTERM)
    return bool(noted)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    previous = exits.raise_on_sigterm()
    try:
        args = _build_parser(argv).parse_args(argv)  # --help and usage errors leave here: no torch, no numba
        if _load_heavy_modules_uninterrupted():
            raise KeyboardInterrupt
        return int(_command_module(args.command).run(args) or 0)
    except MogafaceError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # before a command installs its own handler (imports, start-up)
        print(exits.ending_line(signal.SIGINT), file=sys.stderr)
        return 128 + signal.SIGINT
    except exits.Terminated as stop:
        print(exits.ending_line(stop.number), file=sys.stderr)
        return 128 + stop.number
    except OSError as error:
        if error.errno not in _DISK_ERRORS:
            raise
        print(f"error: {error.filename or ''}: {error.strerror} (nothing half-written was kept)", file=sys.stderr)
        return 2
    finally:
        exits.restore(previous)
