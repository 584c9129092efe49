"""The project's exception types: each names the file, the field and what was expected."""

from __future__ import annotations

import os


class MogafaceError(Exception):
    """Base class of every error the project raises on purpose."""


class InputError(MogafaceError, ValueError):
    """Bad input data: ``InputError(path, field, problem)`` reads as one clear sentence."""

    def __init__(self, path: str | os.PathLike | None, field: str | None, problem: str):
        self.path = os.fspath(path) if path is not None else None
        self.field = field
        self.problem = problem
        where = []
        if self.path is not None:
            where.append(str(self.path))
        if field:
            where.append(f"field '{field}'")
        prefix = ": ".join(where)
        super().__init__(f"{prefix}: {problem}" if prefix else problem)


class ModelFileError(InputError):
    """A head model file (FLAME ``.pkl`` / ``.npz``) that cannot be used."""


class UnsafePickleError(ModelFileError):
    """A pickle asked for a global that the restricted unpickler does not allow."""


class CaptureError(InputError):
    """A capture dataset (GaussianAvatars/VHAP layout) that cannot be used."""
