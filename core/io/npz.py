"""Reproducible, atomic ``.npz`` files, read without ever unpickling."""

from __future__ import annotations

import os
import zipfile

import numpy as np

from ..errors import InputError
from ..limits import MAX_ARRAY_BYTES, MAX_ARRAY_ELEMENTS, MAX_NPZ_MEMBERS
from .archive import check_member_count
from .atomic import atomic_path
from .files import check_regular_file

# A fixed timestamp: the same arrays give the same bytes, so outputs can be compared by hash.
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def save_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray], compress: bool = True) -> None:
    """Write ``arrays`` as an ``.npz`` readable by ``np.load``, atomically and byte-reproducibly."""
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=method) as archive:
            for name, value in arrays.items():
                array = np.asarray(value)
                if array.dtype == object:
                    raise InputError(path, name, "object arrays cannot be stored without pickle")
                info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
                info.compress_type = method
                info.external_attr = 0o644 << 16
                with archive.open(info, "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, array, allow_pickle=False)


def load_npz(path: str | os.PathLike, max_bytes: int = MAX_ARRAY_BYTES) -> dict[str, np.ndarray]:
    """Read every array of an ``.npz`` into memory; pickled (object) members are refused.

    Each member's declared shape and dtype are checked before anything is allocated: no array
    above :data:`~mogaface.core.limits.MAX_ARRAY_ELEMENTS`, and ``max_bytes`` for all together.
    """
    check_regular_file(path)
    check_member_count(path, MAX_NPZ_MEMBERS, "an .npz (zip) archive")
    try:
        with zipfile.ZipFile(path) as archive:
            arrays, total = {}, 0
            for info in archive.infolist():
                name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                with archive.open(info) as member:
                    shape, dtype = _declared(member, path, name)
                    count = int(np.prod(shape, dtype=object))
                    total += count * dtype.itemsize
                    if count > MAX_ARRAY_ELEMENTS or total > max_bytes:
                        raise InputError(path, name, f"declares shape {shape} of {dtype}; the limit is "
                                                     f"{MAX_ARRAY_ELEMENTS} elements and {max_bytes} bytes")
                with archive.open(info) as member:
                    arrays[name] = np.lib.format.read_array(member, allow_pickle=False)
            return arrays
    except InputError:
        raise
    except ValueError as error:
        raise InputError(path, None, f"not a plain numpy archive ({error})") from None
    except (OSError, zipfile.BadZipFile, EOFError, zipfile.LargeZipFile) as error:
        raise InputError(path, None, f"unreadable .npz file ({error})") from None


def _declared(member, path, name) -> tuple[tuple, np.dtype]:
    """Shape and dtype from an ``.npy`` header (no data read)."""
    version = np.lib.format.read_magic(member)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(member)
    elif version in ((2, 0), (3, 0)):
        shape, _, dtype = np.lib.format.read_array_header_2_0(member)
    else:
        raise InputError(path, name, f"unsupported .npy version {version}")
    if dtype.hasobject:
        raise InputError(path, name, "object arrays are refused (they would need pickle)")
    return shape, dtype
