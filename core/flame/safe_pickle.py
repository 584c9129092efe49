"""Read and write FLAME ``.pkl`` files without chumpy and without trusting the pickle.

The official FLAME files are Python 2 pickles (read with ``encoding="latin1"``) whose
arrays are numpy arrays or chumpy ``Ch`` objects and whose ``J_regressor`` is a scipy
sparse matrix. The reader allows exactly the globals those need and turns chumpy and
scipy objects into plain arrays through inert stand-ins, so nothing from the file is
ever executed; any other global (``os.system``, ``builtins.eval``, …) is refused.
"""

from __future__ import annotations

import copyreg
import io
import os
import pickle

import numpy as np

from ..errors import ModelFileError, UnsafePickleError
from ..io.atomic import atomic_open
from ..io.pickle_budget import short_repr
from ..io.restricted_pickle import NUMPY_ARRAY_GLOBALS, restricted_load
from ..limits import MAX_ARRAY_ELEMENTS


class ChumpyArray:
    """Inert stand-in for ``chumpy.ch.Ch``: keeps the wrapped array (``state['x']``)."""

    def __init__(self, x=None):
        self.x = x

    def __setstate__(self, state):
        if isinstance(state, tuple):  # (dict state, slot state)
            state = state[0] or {}
        self.__dict__.update(state if isinstance(state, dict) else {})


class SparseMatrix:
    """Inert stand-in for scipy's ``csc_matrix`` / ``csr_matrix``: keeps the raw arrays."""

    layout = "csc"

    def __setstate__(self, state):
        if isinstance(state, tuple):
            state = state[0] or {}
        self.__dict__.update(state if isinstance(state, dict) else {})

    def to_dense(self) -> np.ndarray:
        shape = tuple(int(n) for n in getattr(self, "_shape", getattr(self, "shape", ())))
        data, indices, indptr = (np.asarray(getattr(self, k)) for k in ("data", "indices", "indptr"))
        if len(shape) != 2:
            raise ValueError("sparse matrix without a 2-D shape")
        if min(shape) < 0 or shape[0] * shape[1] > MAX_ARRAY_ELEMENTS:
            raise ValueError(f"sparse matrix declares shape {shape}, over the limit of {MAX_ARRAY_ELEMENTS} elements")
        dense = np.zeros(shape, dtype=np.float64)
        outer = shape[1] if self.layout == "csc" else shape[0]
        if len(indptr) != outer + 1 or indptr[-1] > len(indices) or len(indices) != len(data):
            raise ValueError("inconsistent sparse matrix arrays")
        for k in range(outer):
            rows = indices[indptr[k] : indptr[k + 1]]
            values = data[indptr[k] : indptr[k + 1]]
            if self.layout == "csc":
                dense[rows, k] = values
            else:
                dense[k, rows] = values
        return dense


class SparseRowMatrix(SparseMatrix):
    layout = "csr"


def _chumpy(name):
    return ChumpyArray if name == "Ch" else None


def _sparse(name):
    return {"csc_matrix": SparseMatrix, "csr_matrix": SparseRowMatrix}.get(name)


# module -> resolver(name) giving the object to use, or None; nothing else may be loaded.
_ALLOWED_MODULES = {
    **NUMPY_ARRAY_GLOBALS,
    "chumpy.ch": _chumpy,
    "chumpy": _chumpy,
    "scipy.sparse.csc": _sparse,
    "scipy.sparse._csc": _sparse,
    "scipy.sparse.csr": _sparse,
    "scipy.sparse._csr": _sparse,
    "scipy.sparse.compressed": _sparse,
    "copy_reg": lambda name: copyreg._reconstructor if name == "_reconstructor" else None,
    "copyreg": lambda name: copyreg._reconstructor if name == "_reconstructor" else None,
    "__builtin__": lambda name: {"object": object, "bytes": _empty_bytes}.get(name),
    "builtins": lambda name: {"object": object, "bytes": _empty_bytes}.get(name),
    "_codecs": lambda name: latin1_encode if name == "encode" else None,
}


def _empty_bytes(*args):
    """Python 3 pickles (protocol 2) store an empty array's data as ``bytes()``; only that is allowed
    (``bytes(n)`` would allocate what the file asks)."""
    if args:
        raise UnsafePickleError(None, None, f"refused bytes() with the arguments {short_repr(args)}: expected none (an "
                                            f"empty array's data)")
    return b""


def latin1_encode(text, encoding="latin1"):
    """Python 3 pickles of ``bytes`` call ``_codecs.encode(str, 'latin1')``; only that is allowed."""
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise UnsafePickleError(None, None, f"refused _codecs.encode{short_repr((text, encoding))}: expected a text "
                                            f"and 'latin1' (how Python 3 pickles bytes)")
    return text.encode("latin1")


def _plain(value):
    """Turn chumpy / sparse stand-ins into numpy arrays; leave everything else as it is."""
    if isinstance(value, ChumpyArray):
        if not hasattr(value, "x"):
            raise ValueError("chumpy object without its array 'x'")
        return np.asarray(value.x)
    if isinstance(value, SparseMatrix):
        return value.to_dense()
    return value


def load_model_pickle(path: str | os.PathLike) -> dict:
    """Read a FLAME ``.pkl`` into a dict of plain values (arrays, strings), executing nothing."""
    try:
        raw = restricted_load(path, _ALLOWED_MODULES, "a FLAME model file")
    except UnsafePickleError:
        raise
    except FileNotFoundError:
        raise ModelFileError(path, None, "file not found") from None
    except Exception as error:  # truncated or corrupt pickles raise many different types
        raise ModelFileError(path, None, f"not a readable FLAME pickle ({type(error).__name__}: {error})") from None
    if not isinstance(raw, dict):
        raise ModelFileError(path, None, f"expected a pickled dict of arrays, found {type(raw).__name__}")
    result = {}
    for key, value in raw.items():
        try:
            result[str(key)] = _plain(value)
        except ValueError as error:
            raise ModelFileError(path, str(key), str(error)) from None
    return result


class _ChumpyWriter(pickle._Pickler):
    """Writes ``ChumpyArray`` as the global ``chumpy.ch.Ch``, as the official files do."""

    def save_global(self, obj, name=None):
        if obj is ChumpyArray:
            self.write(pickle.GLOBAL + b"chumpy.ch\nCh\n")
            self.memoize(obj)
            return
        super().save_global(obj, name)

    def reducer_override(self, obj):
        if isinstance(obj, ChumpyArray):
            return copyreg.__newobj__, (ChumpyArray,), {"x": obj.x}
        return NotImplemented


def save_model_pickle(path: str | os.PathLike, model: dict, chumpy_keys: tuple[str, ...] = ()) -> None:
    """Write a FLAME ``.pkl`` (protocol 2, Python 2 readable), atomically.

    ``J_regressor`` is stored as a scipy ``csc_matrix`` like the official files; the
    arrays named in ``chumpy_keys`` are wrapped as chumpy ``Ch`` objects (as FLAME
    2020 does for ``shapedirs``). Without chumpy keys, any unpickler with numpy and
    scipy can read the file.
    """
    import scipy.sparse

    payload = {}
    for key, value in model.items():
        if key == "J_regressor":
            value = scipy.sparse.csc_matrix(np.asarray(value, dtype=np.float64))
        elif key in chumpy_keys:
            value = ChumpyArray(np.asarray(value))
        payload[key] = value
    buffer = io.BytesIO()
    _ChumpyWriter(buffer, protocol=2).dump(payload)
    with atomic_open(path, "wb") as handle:
        handle.write(buffer.getvalue())
