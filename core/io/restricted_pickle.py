"""Unpickle files we did not write without ever executing anything they ask for.

A pickle can name any global and call it; this reader resolves globals only through an
explicit allow-list (module -> resolver(name)), so a file can rebuild numpy arrays and
the few inert stand-ins a caller allows, and every other global is refused by name.
What it may build is bounded too: bytes of arrays (counted before they are allocated) and
objects (``pickle_budget``: opcodes, memo slots, shared references counted as often as they
are reached).
"""

from __future__ import annotations

import os
import pickle
from typing import Callable, Mapping

import numpy as np

from ..errors import UnsafePickleError
from ..limits import MAX_ARRAY_BYTES, MAX_PICKLE_BYTES, MAX_SCALAR_BYTES
from .files import check_regular_file
from .pickle_budget import ObjectBudget, object_budget, scan_opcodes, short_repr

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


class _PendingArray(np.ndarray):
    """An array the unpickler rebuilt, until the load ends: its ``__setstate__`` (the pickle's BUILD)
    is checked first, as numpy's would trust the state's shape (an object list shorter than the shape
    it declares crashes numpy 1.26)."""

    def __setstate__(self, state):
        self._unpickler._check_array_state(state)
        super().__setstate__(state)


def _plain_array(obj):
    return obj.view(np.ndarray) if isinstance(obj, _PendingArray) else obj


class RestrictedUnpickler(pickle.Unpickler):
    """``pickle.Unpickler`` that resolves globals only through ``allowed``.

    ``what`` names the kind of file in the refusal message ("a FLAME model file"), so
    the error says both what was refused and what was expected instead. ``budget`` is the
    number of objects the pickle may build (see ``pickle_budget``).
    """

    def __init__(self, handle, path, allowed: Mapping[str, Resolver], what: str, budget: int,
                 encoding: str = "latin1"):
        super().__init__(handle, encoding=encoding)
        self._path = path
        self._allowed = allowed
        self._what = what
        self._allocated = 0
        self._objects = ObjectBudget(path, budget, _plain_array)

    def load(self):
        try:
            return self._objects.settle(super().load(), "the pickle")
        except UnsafePickleError as error:  # a refusal by a callable the allow-list gave (it has no file)
            if error.path is not None:
                raise
            raise UnsafePickleError(self._path, error.field, error.problem) from None

    def find_class(self, module, name):
        resolver = self._allowed.get(module)
        found = resolver(name) if resolver else None
        if found is None:
            raise UnsafePickleError(self._path, None, f"refused to load global '{module}.{name}' (not part of {self._what})")
        if found is np.ndarray:  # calling it allocates what the file declares: count it first
            return self._new_array
        if found is _numpy_multiarray("_reconstruct"):
            return self._reconstruct
        if found is _numpy_multiarray("scalar"):
            return self._scalar
        if found is np.dtype:  # numpy walks a structured type's field list as a tree
            return self._dtype
        return found

    def _charge(self, shape, dtype) -> None:
        """Count the bytes an array of ``shape`` and ``dtype`` will take against the budget."""
        try:
            dims = [int(n) for n in (shape if isinstance(shape, (tuple, list)) else (shape,))]
            size = int(np.prod(dims, dtype=object)) * np.dtype(dtype).itemsize
        except (TypeError, ValueError) as error:
            raise UnsafePickleError(self._path, None, f"refused an array of shape {short_repr(shape)} "
                                                      f"({short_repr(error)})") from None
        if min(dims, default=0) < 0 or size > MAX_ARRAY_BYTES or self._allocated + size > MAX_PICKLE_BYTES:
            raise UnsafePickleError(self._path, None, f"refused an array of shape {short_repr(shape)} and dtype "
                                                      f"{short_repr(dtype)}: over the limit of {MAX_ARRAY_BYTES} "
                                                      f"bytes an array and {MAX_PICKLE_BYTES} in all")
        self._allocated += size

    def _new_array(self, shape, dtype=float, *args, **kwargs):
        shape, dtype, args = self._objects.settle((shape, dtype, args), "numpy.ndarray's arguments")
        self._charge(shape, dtype)
        array = _PendingArray(shape, dtype, *args, **kwargs)
        array._unpickler = self
        return array

    def _reconstruct(self, subtype, shape, dtype):
        if subtype not in (np.ndarray, self._new_array):
            raise UnsafePickleError(self._path, None, f"refused to rebuild an array of type {short_repr(subtype)}")
        shape, dtype = self._objects.settle((shape, dtype), "an array rebuild's arguments")
        self._charge(shape, dtype)
        array = _numpy_multiarray("_reconstruct")(_PendingArray, shape, dtype)
        array._unpickler = self
        return array

    def _check_array_state(self, state) -> None:
        """An array's BUILD state ``([version,] shape, dtype, fortran, data)`` must hold what it declares."""
        state = self._objects.settle(state, "an array's state")
        if not isinstance(state, tuple) or len(state) not in (4, 5):
            raise UnsafePickleError(self._path, None, f"refused an array state {short_repr(state)}")
        shape, dtype, _, data = state[-4:]
        if not isinstance(dtype, np.dtype):
            raise UnsafePickleError(self._path, None, f"refused an array state with dtype {short_repr(dtype)}")
        self._charge(shape, dtype)
        count = int(np.prod([int(n) for n in shape], dtype=object)) if isinstance(shape, (tuple, list)) else -1
        if dtype.hasobject:
            if dtype != np.dtype(object) or not isinstance(data, list) or len(data) != count:
                raise UnsafePickleError(self._path, None, f"refused an object array state: shape {short_repr(shape)} "
                                                          f"with {len(data) if isinstance(data, list) else 'no'} "
                                                          f"elements listed")
        elif not isinstance(data, (bytes, str)) or len(data) != count * dtype.itemsize:
            raise UnsafePickleError(self._path, None, f"refused an array state: shape {short_repr(shape)} of "
                                                      f"{dtype} needs {count * dtype.itemsize} bytes of data")

    def _scalar(self, dtype, *data):
        """numpy's scalar rebuild; without data it allocates the dtype's whole item size, and a real
        scalar is a number or a short string."""
        dtype, data = self._objects.settle((dtype, data), "a numpy scalar's arguments")
        if not isinstance(dtype, np.dtype) or dtype.itemsize > MAX_SCALAR_BYTES:
            raise UnsafePickleError(self._path, None, f"refused a numpy scalar of type {short_repr(dtype)} "
                                                      f"(at most {MAX_SCALAR_BYTES} bytes)")
        return _numpy_multiarray("scalar")(dtype, *data)

    def _dtype(self, *args):
        args = self._objects.settle(args, "numpy.dtype's arguments")
        return np.dtype(*args)

    def persistent_load(self, pid):
        raise UnsafePickleError(self._path, None, "refused a persistent reference in the pickle")


def restricted_load(path: str | os.PathLike, allowed: Mapping[str, Resolver], what: str, offset: int = 0):
    """Read one pickled object from ``path`` (starting at byte ``offset``: the pickle inside a
    ``.npy`` file) with :class:`RestrictedUnpickler`.

    Only the unpickler's own refusals surface as :class:`UnsafePickleError`; opening and
    decoding errors propagate for the caller to turn into its own message.
    """
    check_regular_file(path)
    with open(path, "rb") as handle:
        budget = object_budget(max(os.fstat(handle.fileno()).st_size - offset, 0))
        scan_opcodes(handle, path, budget, offset)
        return RestrictedUnpickler(handle, path, allowed, what, budget).load()
