"""Our torch files (avatars, MoGaFace modules, checkpoints, refiners): sizes checked, then loaded
``weights_only``.

``torch.load`` allocates every storage its archive lists before anyone sees a shape, so the
archive is read first without building any tensor (:func:`check_torch_archive`): the sizes its
zip records declare, and the storages and tensor views its pickle declares (read by the
restricted unpickler, which refuses every global but torch's tensor rebuilders).
"""

from __future__ import annotations

import collections
import functools
import io
import os
import pickle
import zipfile

import numpy as np

from ..errors import InputError, UnsafePickleError
from ..limits import (
    MAX_ARRAY_ELEMENTS,
    MAX_TORCH_FILE_BYTES,
    MAX_TORCH_PICKLE_BYTES,
    MAX_TORCH_RECORDS,
    TORCH_BYTES_PER_FILE_BYTE,
)
from .archive import check_member_count
from .files import check_regular_file
from .pickle_budget import object_budget, scan_opcodes, short_repr
from .restricted_pickle import RestrictedUnpickler


def load_torch_state(path: str | os.PathLike, what: str) -> dict:
    """Read ``path`` with ``weights_only`` (nothing in it is executed) after checking every size it
    declares (:func:`check_torch_archive`); errors name the file."""
    import torch

    check_torch_archive(path, what)
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except Exception as error:
        raise InputError(path, None, f"not a readable {what} ({error})") from None


def save_torch_state(state, path: str | os.PathLike) -> None:
    """``torch.save`` to ``path`` (a temporary name); a full or read-only disk is a clear error."""
    import torch

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


# -- sizes before torch.load ------------------------------------------------------------------

def check_torch_archive(path: str | os.PathLike, what: str) -> None:
    """Refuse a torch file whose declared sizes are out of bounds, allocating nothing they declare.

    The zip records: at most :data:`MAX_TORCH_RECORDS`, each within the file, and together at most
    :data:`MAX_TORCH_FILE_BYTES` once inflated and :data:`TORCH_BYTES_PER_FILE_BYTE` times the file's
    size (``torch.save`` stores records uncompressed; a deflated bomb of zeros is a thousand times
    larger inflated). The pickle: only torch's tensor globals; every storage no larger than its
    record, every tensor view within its storage and at most :data:`MAX_ARRAY_ELEMENTS` elements.
    """
    check_regular_file(path)
    check_member_count(path, MAX_TORCH_RECORDS, f"a torch archive ({_article(what)} {what} is one)")
    size = os.stat(path).st_size
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
            declared = 0
            for info in infos:
                declared += info.file_size
                if info.header_offset + info.compress_size > size:
                    raise InputError(path, info.filename, f"record of {info.compress_size} bytes runs past the "
                                                          f"end of the file ({size} bytes)")
            limit = min(MAX_TORCH_FILE_BYTES, TORCH_BYTES_PER_FILE_BYTE * size)
            if declared > limit:
                raise InputError(path, None, f"declares {declared} bytes of records in a file of {size} bytes; "
                                             f"the limit is {limit} ({TORCH_BYTES_PER_FILE_BYTE}x the file's size, "
                                             f"at most {MAX_TORCH_FILE_BYTES}; see docs/safety.md)")
            pickles = [info for info in infos if info.filename.rpartition("/")[2] == "data.pkl"]
            if len(pickles) != 1:
                raise InputError(path, None, f"not a {what} (expected one data.pkl in a torch archive, "
                                             f"found {len(pickles)})")
            prefix = pickles[0].filename[:-len("data.pkl")]
            if pickles[0].file_size > MAX_TORCH_PICKLE_BYTES:
                raise InputError(path, pickles[0].filename, f"a pickle of {pickles[0].file_size} bytes; the limit "
                                                            f"is {MAX_TORCH_PICKLE_BYTES}")
            records = {info.filename[len(prefix) + len("data/"):]: info for info in infos
                       if info.filename.startswith(prefix + "data/")}
            data = archive.read(pickles[0])
    except InputError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError) as error:
        raise InputError(path, None, f"not a readable {what} (not a torch archive: {error})") from None
    _scan_pickle(path, data, records, what)


def _article(what: str) -> str:
    return "an" if what[:1] in "aeiou" else "a"


def _scan_pickle(path, data: bytes, records: dict, what: str) -> None:
    handle = io.BytesIO(data)
    budget = object_budget(len(data))
    try:
        scan_opcodes(handle, path, budget)
        _TorchDeclarations(handle, path, records, what, budget).load()
    except UnsafePickleError as error:
        raise InputError(path, "data.pkl", error.problem) from None
    except InputError:
        raise
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError) as error:
        raise InputError(path, None, f"not a readable {what} (damaged data.pkl: {short_repr(error)})") from None


class _Storage:
    """What a pickle declares of one storage: its record and its size in bytes."""

    def __init__(self, key: str, nbytes: int, itemsize: int):
        self.key, self.nbytes, self.itemsize = key, nbytes, itemsize


class _StorageType:
    """Stands in for ``torch.FloatStorage`` and the like: only the item size matters here."""

    def __init__(self, name: str, itemsize: int):
        self.name, self.itemsize = name, itemsize


@functools.cache
def _storage_types() -> dict[str, _StorageType]:
    """``torch.FloatStorage``, ``torch.LongStorage``, ...: the typed storage names a pickle uses."""
    import torch

    types = {}
    for name in dir(torch):
        dtype = getattr(getattr(torch, name, None), "_dtype", None) if name.endswith("Storage") else None
        if isinstance(dtype, torch.dtype):
            types[name] = _StorageType(name, dtype.itemsize)
    return types


def _torch_resolver(name: str):
    import torch

    found = _storage_types().get(name)
    if found is not None:
        return found
    value = getattr(torch, name, None)
    if isinstance(value, torch.dtype):
        return value
    return {"Size": tuple}.get(name)


class _TorchDeclarations(RestrictedUnpickler):
    """Reads a torch ``data.pkl`` into stand-ins, checking each storage and view as it is declared."""

    def __init__(self, handle, path, records: dict, what: str, budget: int):
        allowed = {
            "torch": _torch_resolver,
            "torch._utils": {"_rebuild_tensor_v2": self._tensor, "_rebuild_parameter": self._parameter,
                             "_rebuild_parameter_with_state": self._parameter}.get,
            "collections": {"OrderedDict": collections.OrderedDict}.get,
        }
        super().__init__(handle, path, allowed, f"{_article(what)} {what}", budget, encoding="utf-8")
        self._records = records
        self._storages: dict[str, _Storage] = {}
        self._view_bytes = 0

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"):
            raise UnsafePickleError(self._path, None, f"refused a persistent reference {short_repr(pid)}")
        _, kind, key, _location, numel = pid
        if not isinstance(kind, _StorageType) or not isinstance(key, str) or not isinstance(numel, int) or numel < 0:
            raise UnsafePickleError(self._path, None, f"refused a storage reference {short_repr(pid)}")
        if key in self._storages:
            return self._storages[key]
        record = self._records.get(key)
        nbytes = numel * kind.itemsize
        if record is None:
            raise UnsafePickleError(self._path, None, f"storage {key!r} has no record data/{key}")
        if nbytes > record.file_size:
            raise UnsafePickleError(self._path, None, f"storage {key!r} declares {numel} elements of {kind.name} "
                                                      f"({nbytes} bytes); its record holds {record.file_size}")
        self._storages[key] = _Storage(key, nbytes, kind.itemsize)
        return self._storages[key]

    def _tensor(self, storage, offset, size, stride, *rest):
        if not isinstance(storage, _Storage):
            raise UnsafePickleError(self._path, None, f"refused a tensor over {short_repr(storage)}")
        size, stride = self._objects.settle((size, stride), "a tensor's shape")
        ok = (isinstance(offset, int) and isinstance(size, tuple) and isinstance(stride, tuple)
              and len(size) == len(stride) and len(size) <= 64
              and all(isinstance(n, int) and n >= 0 for n in size + stride) and offset >= 0)
        if not ok:
            raise UnsafePickleError(self._path, None, f"refused a tensor of shape {short_repr(size)}, strides "
                                                      f"{short_repr(stride)}")
        count = int(np.prod(size, dtype=object))
        if count > MAX_ARRAY_ELEMENTS:
            raise UnsafePickleError(self._path, None, f"a tensor declares shape {short_repr(size)}; the limit is "
                                                      f"{MAX_ARRAY_ELEMENTS} elements")
        end = offset + sum((n - 1) * s for n, s in zip(size, stride)) + 1 if count else 0
        if end * storage.itemsize > storage.nbytes:
            raise UnsafePickleError(self._path, None, f"a tensor of shape {short_repr(size)} reaches past the end "
                                                      f"of its storage {storage.key!r}")
        self._view_bytes += count * storage.itemsize
        if self._view_bytes > MAX_TORCH_FILE_BYTES:
            raise UnsafePickleError(self._path, None, f"its tensors declare more than {MAX_TORCH_FILE_BYTES} bytes "
                                                      f"together")
        return ("tensor", storage.key, size)

    def _parameter(self, data, *rest):
        return data
