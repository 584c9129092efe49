"""Unpickle files we did not write without ever executing anything they ask for.

A pickle can name any global and call it; this reader resolves globals only through an
explicit allow-list (module -> resolver(name)), so a file can rebuild numpy arrays and
the few inert stand-ins a caller allows, and every other global is refused by name.
"""

from __future__ import annotations

import os
import pickle
from typing import Callable, Mapping

import numpy as np

from ..errors import UnsafePickleError

# resolver(name) -> the object to use for ``module.name``, or None to refuse it.
Resolver = Callable[[str], object]


def _numpy_multiarray(name: str):
    """numpy's own array and scalar rebuilders (``numpy._core`` in numpy 2, ``numpy.core`` before)."""
    if name not in ("_reconstruct", "scalar"):
        return None
    try:
        from numpy._core import multiarray
    except ImportError:
        from numpy.core import multiarray
    return getattr(multiarray, name)


# What a pickle of plain numpy arrays (any protocol, numpy 1 or 2) needs, and nothing more.
NUMPY_ARRAY_GLOBALS: dict[str, Resolver] = {
    "numpy.core.multiarray": _numpy_multiarray,
    "numpy._core.multiarray": _numpy_multiarray,
    "numpy": lambda name: {"ndarray": np.ndarray, "dtype": np.dtype}.get(name),
}


class RestrictedUnpickler(pickle.Unpickler):
    """``pickle.Unpickler`` that resolves globals only through ``allowed``.

    ``what`` names the kind of file in the refusal message ("a FLAME model file"), so
    the error says both what was refused and what was expected instead.
    """

    def __init__(self, handle, path, allowed: Mapping[str, Resolver], what: str, encoding: str = "latin1"):
        super().__init__(handle, encoding=encoding)
        self._path = path
        self._allowed = allowed
        self._what = what

    def find_class(self, module, name):
        resolver = self._allowed.get(module)
        found = resolver(name) if resolver else None
        if found is None:
            raise UnsafePickleError(self._path, None, f"refused to load global '{module}.{name}' (not part of {self._what})")
        return found

    def persistent_load(self, pid):
        raise UnsafePickleError(self._path, None, "refused a persistent reference in the pickle")


def restricted_load(path: str | os.PathLike, allowed: Mapping[str, Resolver], what: str):
    """Read one pickled object from ``path`` with :class:`RestrictedUnpickler`.

    Only the unpickler's own refusals surface as :class:`UnsafePickleError`; opening and
    decoding errors propagate for the caller to turn into its own message.
    """
    with open(path, "rb") as handle:
        return RestrictedUnpickler(handle, path, allowed, what).load()
