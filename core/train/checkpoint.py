"""Training checkpoints: atomic files of tensors and plain values, a ``latest`` pointer, rotation.

``RUN/checkpoints/step_{step:06d}.pt`` holds everything a resumed run needs to continue exactly
(see :meth:`mogaface.core.train.trainer.Trainer.state`); ``RUN/checkpoints/latest`` is a text
file with the name of the newest one, replaced atomically after the checkpoint is complete, so a
kill at any moment leaves a usable pair. Files load with ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import os
import pathlib
import re

from ..errors import InputError
from ..io.torch_file import check_format, load_torch_state, save_torch_state
from ..io.atomic import atomic_path, write_text

CHECKPOINT_FORMAT = "mogaface-train-checkpoint"
CHECKPOINT_VERSION = 1
LATEST = "latest"
_NAME = re.compile(r"^step_(\d{6,})\.pt$")


def checkpoint_name(step: int) -> str:
    return f"step_{step:06d}.pt"


def save_checkpoint(folder: str | os.PathLike, step: int, state: dict, keep: int = 3) -> pathlib.Path:
    """Write ``state`` as the checkpoint of ``step``, point ``latest`` at it, keep the newest ``keep``."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / checkpoint_name(step)
    with atomic_path(path) as tmp:
        save_torch_state({"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "step": step, **state}, tmp)
    write_text(folder / LATEST, path.name + "\n")
    for old in list_checkpoints(folder)[:-keep]:
        if old != path:
            old.unlink(missing_ok=True)
    return path


def list_checkpoints(folder: str | os.PathLike) -> list[pathlib.Path]:
    """Checkpoint files in ``folder``, oldest step first."""
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _NAME.match(p.name))]
    return [p for _, p in sorted(found)]


def latest_checkpoint(folder: str | os.PathLike) -> pathlib.Path | None:
    """The checkpoint ``latest`` names (else the highest step found), or None."""
    folder = pathlib.Path(folder)
    pointer = folder / LATEST
    if pointer.is_file():
        name = pointer.read_text(encoding="utf-8").strip()
        if _NAME.match(name) and (folder / name).is_file():
            return folder / name
    found = list_checkpoints(folder)
    return found[-1] if found else None


def load_checkpoint(path: str | os.PathLike) -> dict:
    """Read a checkpoint (``weights_only``: nothing in it is executed) and check its format."""
    state = load_torch_state(path, "checkpoint")
    check_format(state, path, CHECKPOINT_FORMAT, CHECKPOINT_VERSION)
    return state


def remove_partials(folder: str | os.PathLike) -> list[pathlib.Path]:
    """Delete the temporary files a killed writer left in ``folder`` (``.*.partial*``)."""
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        return []
    removed = [p for p in folder.iterdir() if p.name.startswith(".") and ".partial" in p.name and p.is_file()]
    for p in removed:
        p.unlink(missing_ok=True)
    return removed


def newest_intact_checkpoint(folder: str | os.PathLike) -> tuple[pathlib.Path, dict, list[str]]:
    """The newest checkpoint that loads, its state, and why each newer one was skipped.

    ``latest`` is tried first, then every other checkpoint from the highest step down, so a
    truncated or corrupt newest file costs one interval, not the run.
    """
    folder = pathlib.Path(folder)
    first = latest_checkpoint(folder)
    if first is None:
        raise InputError(folder, None, "no checkpoint to resume from")
    candidates = [first] + [p for p in reversed(list_checkpoints(folder)) if p != first]
    skipped = []
    for path in candidates:
        try:
            return path, load_checkpoint(path), skipped
        except InputError as error:
            skipped.append(str(error))
    raise InputError(folder, None, "no intact checkpoint to resume from: " + "; ".join(skipped))
