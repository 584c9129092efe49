"""Reproducible, atomic ``.npz`` files, read without ever unpickling."""

from __future__ import annotations

import os
import zipfile

import numpy as np

from ..errors import InputError
from .atomic import atomic_path

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


def load_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read every array of an ``.npz`` into memory; pickled (object) members are refused."""
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except ValueError as error:
        raise InputError(path, None, f"not a plain numpy archive ({error})") from None
    except (OSError, zipfile.BadZipFile, EOFError) as error:
        raise InputError(path, None, f"unreadable .npz file ({error})") from None
