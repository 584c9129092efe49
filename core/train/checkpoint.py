"""Training checkpoints: atomic files of tensors and plain values, a ``latest`` pointer, rotation.

``RUN/checkpoints/step_{step:06d}.pt`` holds everything a resumed run needs to continue exactly
(see :meth:`mogaface.core.train.trainer.Trainer.state`); ``RUN/checkpoints/latest`` is a text
file with the name of the newest one, replaced atomically after the checkpoint is complete. The
pointer is a hint for readers outside (Blender's "resume if there is a checkpoint"): resuming
takes the newest checkpoint that loads, whatever the pointer says, so a kill between a
checkpoint and its pointer loses nothing. A checkpoint that does not load (damaged, or refused:
a pickle that would run code, sizes out of bounds) is set aside as ``NAME.refused`` so the
resumed run's own checkpoint of that step never overwrites it. Files load with
``torch.load(weights_only=True)`` after their declared sizes are checked.
"""

from __future__ import annotations

import os
import pathlib
import re
from typing import TYPE_CHECKING

from ..errors import InputError
from ..io.atomic import atomic_path, write_text
from ..io.torch_file import check_format, load_torch_state, save_torch_state
from ..run.names import AVATAR_FILE, CHECKPOINT_DIR

CHECKPOINT_FORMAT = "mogaface-train-checkpoint"
CHECKPOINT_VERSION = 1
LATEST = "latest"
REFUSED = ".refused"  # the suffix of a checkpoint set aside because it did not load
_NAME = re.compile(r"^step_(\d{6,})\.pt$")

if TYPE_CHECKING:
    from ..run.folder import RunFolder
    from .run_lock import RunLock


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
    """The checkpoint of the highest step found (the ``latest`` pointer may lag behind it), or None."""
    found = list_checkpoints(folder)
    return found[-1] if found else None


def has_checkpoint(run_root: str | os.PathLike) -> bool:
    """Whether a run folder holds a checkpoint: the one test of "can this run continue" (the
    command line, the ablation, Blender). Checkpoint files are looked for, not the ``latest``
    pointer (it may lag or be lost)."""
    return latest_checkpoint(pathlib.Path(run_root) / CHECKPOINT_DIR) is not None


def resumable(run_root: str | os.PathLike) -> bool:
    """Whether a run folder holds a checkpoint and no finished avatar: what Blender's "Auto" resumes."""
    return has_checkpoint(run_root) and not (pathlib.Path(run_root) / AVATAR_FILE).exists()


def load_checkpoint(path: str | os.PathLike) -> dict:
    """Read a checkpoint (``weights_only``: nothing in it is executed) and check its format."""
    state = load_torch_state(path, "checkpoint")
    check_format(state, path, CHECKPOINT_FORMAT, CHECKPOINT_VERSION)
    return state


def newest_intact_checkpoint(folder: str | os.PathLike) -> tuple[pathlib.Path, dict, list[str]]:
    """The newest checkpoint that loads, its state, and why each newer one was skipped.

    Checkpoints are tried from the highest step down (the ``latest`` pointer is not trusted: a
    kill between a checkpoint and its pointer leaves it one behind), so a truncated, corrupt or
    refused newest file costs one interval, not the run.
    """
    folder = pathlib.Path(folder)
    candidates = list(reversed(list_checkpoints(folder)))
    if not candidates:
        raise InputError(folder, None, "no checkpoint to resume from")
    skipped = []
    for path in candidates:
        try:
            return path, load_checkpoint(path), skipped
        except InputError as error:
            skipped.append(str(error))
    raise InputError(folder, None, "no intact checkpoint to resume from: " + "; ".join(skipped))


def set_aside_newer(folder: str | os.PathLike, used: pathlib.Path) -> list[str]:
    """Rename every checkpoint of a step above ``used`` (resuming skipped each: it did not load) to
    ``NAME.refused``, kept for inspection and never overwritten by the resumed run; a note for each."""
    notes = []
    for path in list_checkpoints(folder):
        if int(_NAME.match(path.name).group(1)) <= int(_NAME.match(used.name).group(1)):
            continue
        aside = path.with_name(path.name + REFUSED)
        number = 1
        while aside.exists() or aside.is_symlink():
            aside, number = path.with_name(f"{path.name}.{number}{REFUSED}"), number + 1
        path.rename(aside)
        notes.append(f"kept the checkpoint that did not load as {aside.name}")
    return notes


def resume_notes(folder: pathlib.Path, used: pathlib.Path, skipped: list[str], lock: RunLock) -> list[str]:
    """What a resumed run should tell its user: stale lock, cleaned temporary files, skipped checkpoints."""
    notes = []
    if lock.previous_owner is not None:
        notes.append(f"took over the lock of process {lock.previous_owner}, which is no longer running")
    if lock.removed_partials:
        notes.append(f"removed {len(lock.removed_partials)} unfinished temporary file(s) of a killed run")
    for problem in skipped:
        notes.append(f"skipped a damaged checkpoint ({problem})")
    if skipped:
        notes.append(f"resuming from {used.name}, the newest intact checkpoint in {folder}")
    return notes


def starting_state(run_folder: RunFolder, resume: bool, lock: RunLock | None) -> tuple[dict | None, list[str]]:
    """Where a run in ``run_folder`` starts: ``(None, [])`` for a fresh run, after checking that the
    folder holds no run yet; for ``resume``, the state of the newest checkpoint that loads and what
    to tell the user. The writer (``lock``: the folder's lock it holds; None on other ranks) also
    sets each newer checkpoint that did not load aside (:func:`set_aside_newer`)."""
    folder = run_folder.checkpoint_dir
    if not resume:
        if has_checkpoint(run_folder.root) or run_folder.avatar_path.exists():
            raise InputError(run_folder.root, None, "already holds a run (resume it with --resume, "
                                                    "or choose another folder)")
        return None, []
    path, state, skipped = newest_intact_checkpoint(folder)
    notes = []
    if lock is not None:
        notes = resume_notes(folder, path, skipped, lock) + set_aside_newer(folder, path)
    return state, notes
