"""A training command started through a launcher the user configures, e.g. ``torchrun --nproc_per_node 2``.

Data-parallel training (docs/training.md) runs under torchrun; which machines take part is the
user's business (their launcher line: ``--nnodes``, ``--rdzv-endpoint`` …). We only put that prefix
in front of the same ``-m mogaface train …`` arguments and never start remote work ourselves.
"""

from __future__ import annotations

import shlex

from ..errors import InputError
from .worker import module_arguments


def with_launcher(command: list[str], launcher: str) -> list[str]:
    """``command`` (a :func:`~mogaface.core.for_blender.worker.worker_command`) run by ``launcher`` as ``-m mogaface …``.

    The launcher starts its own Python processes, so the package must be importable there (an
    installed ``mogaface``); the isolated start of a plain worker does not carry over. An empty
    launcher leaves the command as it is.
    """
    if not launcher.strip():
        return list(command)
    try:
        prefix = shlex.split(launcher)
    except ValueError as error:
        raise InputError(None, "launcher", f"not a command line ({error}): {launcher!r}") from None
    return prefix + module_arguments(command)


def launcher_arguments(launcher: str, resume: bool) -> list[str]:
    """The ``train`` options a launched run adds: one image per rank a step (``--batch auto``),
    kept to the images seen under :data:`~mogaface.core.train.config.LAUNCHED_BATCH_RULE`, so the
    ranks shorten the run instead of lengthening it; a resumed run keeps its own settings."""
    from ..train.config import LAUNCHED_BATCH_RULE

    if not launcher.strip() or resume:
        return []
    return ["--batch", "auto", "--batch-rule", LAUNCHED_BATCH_RULE]
