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
from .files import check_regular_file
from ..limits import MAX_ARRAY_BYTES, MAX_PICKLE_BYTES

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
        self._allocated = 0

    def find_class(self, module, name):
        resolver = self._allowed.get(module)
        found = resolver(name) if resolver else None
        if found is None:
            raise UnsafePickleError(self._path, None, f"refused to load global '{module}.{name}' (not part of {self._what})")
        if found is np.ndarray:  # calling it allocates what the file declares: count it first
            return self._new_array
        if getattr(found, "__name__", None) == "_reconstruct" and found is _numpy_multiarray("_reconstruct"):
            return self._reconstruct
        return found

    def _charge(self, shape, dtype) -> None:
        """Count the bytes an array of ``shape`` and ``dtype`` will take against the budget."""
        try:
            dims = [int(n) for n in (shape if isinstance(shape, (tuple, list)) else (shape,))]
            size = int(np.prod(dims, dtype=object)) * np.dtype(dtype).itemsize
        except (TypeError, ValueError) as error:
            raise UnsafePickleError(self._path, None, f"refused an array of shape {shape!r} ({error})") from None
        if min(dims, default=0) < 0 or size > MAX_ARRAY_BYTES or self._allocated + size > MAX_PICKLE_BYTES:
            raise UnsafePickleError(self._path, None, f"refused an array of shape {shape!r} and dtype {dtype!r}: "
                                                      f"over the limit of {MAX_ARRAY_BYTES} bytes an array and "
                                                      f"{MAX_PICKLE_BYTES} in all")
        self._allocated += size

    def _new_array(self, shape, dtype=float, *args, **kwargs):
        self._charge(shape, dtype)
        return np.ndarray(shape, dtype, *args, **kwargs)

    def _reconstruct(self, subtype, shape, dtype):
        if subtype not in (np.ndarray, self._new_array):
            raise UnsafePickleError(self._path, None, f"refused to rebuild an array of type {subtype!r}")
        self._charge(shape, dtype)
        return _numpy_multiarray("_reconstruct")(np.ndarray, shape, dtype)

    def persistent_load(self, pid):
        raise UnsafePickleError(self._path, None, "refused a persistent reference in the pickle")


def nested_elements(value, limit: int) -> int:
    """How many elements ``np.asarray(value)`` would hold, counted without expanding anything.

    A pickle can make a list of a thousand references to one list of a thousand references to…
    in a few bytes; the array made from it is the product. Each distinct container is counted once
    (by identity), so the walk costs what the pickle stored, and it stops as soon as ``limit`` is
    passed (the count returned is then above ``limit``).
    """
    counted: dict[int, int] = {}

    def count(item, depth: int) -> int:
        if isinstance(item, np.ndarray):
            return int(item.size)
        if not isinstance(item, (list, tuple)):
            return 1
        if depth > 64:  # numpy arrays have at most 64 dimensions
            return limit + 1
        key = id(item)
        if key not in counted:
            total = 0
            for child in item:
                total += count(child, depth + 1)
                if total > limit:
                    break
            counted[key] = total
        return counted[key]

    return count(value, 0)


def restricted_load(path: str | os.PathLike, allowed: Mapping[str, Resolver], what: str):
    """Read one pickled object from ``path`` with :class:`RestrictedUnpickler`.

    Only the unpickler's own refusals surface as :class:`UnsafePickleError`; opening and
    decoding errors propagate for the caller to turn into its own message.
    """
    check_regular_file(path)
    with open(path, "rb") as handle:
        return RestrictedUnpickler(handle, path, allowed, what).load()
