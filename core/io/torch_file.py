"""Our torch files (avatars, MoGaFace modules, checkpoints): loaded ``weights_only``, checked."""

from __future__ import annotations

import os

import torch

from ..errors import InputError


def load_torch_state(path: str | os.PathLike, what: str) -> dict:
    """Read ``path`` with ``weights_only`` (nothing in it is executed); errors name the file."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except Exception as error:
        raise InputError(path, None, f"not a readable {what} ({error})") from None


def save_torch_state(state, path: str | os.PathLike) -> None:
    """``torch.save`` to ``path`` (a temporary name); a full or read-only disk is a clear error."""
    try:
        torch.save(state, path)
    except (OSError, RuntimeError) as error:
        raise InputError(path, None, f"cannot write (disk full or not writable? {error})") from None


def check_format(state, source, file_format: str, version: int) -> None:
    """Refuse a state that is not a dict of ``file_format`` at ``version``."""
    if not isinstance(state, dict) or state.get("format") != file_format:
        raise InputError(source, "format", f"expected a {file_format} file")
    if state.get("version") != version:
        raise InputError(source, "version", f"expected version {version}, found {state.get('version')}")
