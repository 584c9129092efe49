"""A training command started through a launcher the user configures, e.g. ``torchrun --nproc_per_node 2``.

Data-parallel training (docs/training.md) runs under torchrun; which machines take part is the
user's business (their launcher line: ``--nnodes``, ``--rdzv-endpoint`` …). We only put that prefix
in front of the same ``-m mogaface train …`` arguments and never start remote work ourselves.
"""

from __future__ import annotations

import shlex

from .errors import InputError


def with_launcher(command: list[str], launcher: str) -> list[str]:
    """``command`` (``[python, …, "-m", package, …]``) with the interpreter part replaced by ``launcher``.

    An empty launcher leaves the command as it is.
    """
    if not launcher.strip():
        return list(command)
    try:
        prefix = shlex.split(launcher)
    except ValueError as error:
        raise InputError(None, "launcher", f"not a command line ({error}): {launcher!r}") from None
    if "-m" not in command:
        raise InputError(None, "launcher", "the training command does not run a module (-m)")
    return prefix + command[command.index("-m"):]
