"""Gaussian splat PLY files in the layout of the original 3DGS code, which viewers read.

One binary little-endian ``vertex`` element of float properties, in this order:
``x y z nx ny nz f_dc_0..2 f_rest_0..M-1 opacity scale_0..2 rot_0..3``. Values are stored
as trained, not activated: log-scales, logit opacity, quaternion ``w x y z`` (``rot_0`` is
``w``), SH coefficients with ``f_rest`` channel-major (every R coefficient, then G, then B),
so ``M = 3 * ((d + 1)^2 - 1)`` for SH degree ``d``. Normals are written as zeros.

GaussianAvatars stores its triangle-bound Gaussians in the same layout with one more
property, ``binding_0``, the index of the face each Gaussian is bound to (its loader
matches properties named ``binding_<i>``); we write it as ``int`` and read either type (its
``save_ply`` writes every property, ``binding_0`` too, as ``float``: whole numbers are ids).
"""

from __future__ import annotations

import math
import os

import numpy as np

from ..errors import InputError
from ..limits import MAX_PLY_VERTICES
from .atomic import atomic_open
from .files import check_regular_file

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_MAX_HEADER_BYTES = 1 << 20


def gaussian_property_names(sh_degree: int, with_binding: bool = False) -> list[str]:
    """The property names, in file order, for Gaussians of SH degree ``sh_degree``."""
    rest = 3 * ((sh_degree + 1) ** 2 - 1)
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return names + (["binding_0"] if with_binding else [])


def _sh_degree(coefficients: int) -> int | None:
    degree = math.isqrt(coefficients) - 1
    return degree if coefficients >= 1 and (degree + 1) ** 2 == coefficients else None


def _numpy(value) -> np.ndarray:
    """Arrays or torch tensors (detached, moved to the CPU) as numpy arrays."""
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value)


def _float_field(path, name, value, width: int) -> np.ndarray:
    """``value`` as float64 ``(N, width)``; ``(N,)`` is accepted for ``width == 1``."""
    array = _numpy(value).astype(np.float64)
    if width == 1 and array.ndim == 1:
        array = array[:, None]
    if array.ndim != 2 or array.shape[1] != width:
        expected = "(N,)" if width == 1 else f"(N, {width})"
        raise InputError(path, name, f"expected shape {expected}, found {np.shape(value)}")
    if not np.all(np.isfinite(array)):
        raise InputError(path, name, "contains NaN or infinite values")
    return array


def write_gaussian_ply(path, means, scales_log, quats, opacity_logit, sh, binding=None) -> None:
    """Write Gaussians as a 3DGS PLY, atomically.

    ``means (N, 3)``, ``scales_log (N, 3)``, ``quats (N, 4)`` wxyz, ``opacity_logit (N,)``,
    ``sh (N, K, 3)`` with ``K = (d + 1)^2`` (``sh[:, 0]`` is the DC term), optional
    ``binding (N,)`` face ids for GaussianAvatars-style bound Gaussians. numpy arrays
    or torch tensors.
    """
    sh = _numpy(sh).astype(np.float64)
    if sh.ndim != 3 or sh.shape[2] != 3 or _sh_degree(sh.shape[1]) is None:
        raise InputError(path, "sh", f"expected shape (N, (d+1)^2, 3), found {sh.shape}")
    if not np.all(np.isfinite(sh)):
        raise InputError(path, "sh", "contains NaN or infinite values")
    columns = {
        "means": _float_field(path, "means", means, 3),
        "normals": np.zeros((sh.shape[0], 3)),
        "f_dc": sh[:, 0, :],
        "f_rest": sh[:, 1:, :].transpose(0, 2, 1).reshape(sh.shape[0], -1),  # channel-major
        "opacity_logit": _float_field(path, "opacity_logit", opacity_logit, 1),
        "scales_log": _float_field(path, "scales_log", scales_log, 3),
        "quats": _float_field(path, "quats", quats, 4),
    }
    count = sh.shape[0]
    for name, column in columns.items():
        if column.shape[0] != count:
            raise InputError(path, name, f"has {column.shape[0]} rows, expected {count} (one per Gaussian)")
    names = gaussian_property_names(_sh_degree(sh.shape[1]), binding is not None)
    dtype = [(name, "<f4") for name in names if name != "binding_0"]
    if binding is not None:
        binding = _numpy(binding)
        if binding.shape != (count,) or not (np.issubdtype(binding.dtype, np.integer) or binding.size == 0):
            raise InputError(path, "binding", f"expected ({count},) integer face ids, found {binding.shape} {binding.dtype}")
        if binding.size and (binding.min() < 0 or binding.max() >= 2**31):
            raise InputError(path, "binding", "face ids must lie in [0, 2^31)")
        dtype.append(("binding_0", "<i4"))
    table = np.empty(count, dtype=dtype)
    floats = np.concatenate(list(columns.values()), axis=1).astype(np.float32)
    for index, (name, _) in enumerate(dtype[: floats.shape[1]]):
        table[name] = floats[:, index]
    if binding is not None:
        table["binding_0"] = binding
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    header += [f"property {'int' if kind == '<i4' else 'float'} {name}" for name, kind in dtype]
    header.append("end_header")
    with atomic_open(path, "wb") as handle:
        handle.write(("\n".join(header) + "\n").encode("ascii"))
        handle.write(table.tobytes())


def _read_header(path, handle) -> tuple[list[tuple[str, int, list]], int]:
    """Parse the header: ``[(element, count, [(property, dtype or None for lists)])]``, data offset."""
    if handle.readline().rstrip(b"\r\n") != b"ply":
        raise InputError(path, None, "not a PLY file (no 'ply' magic line)")
    elements, binary = [], False
    while True:
        line = handle.readline()
        if not line or handle.tell() > _MAX_HEADER_BYTES:
            raise InputError(path, None, "PLY header has no 'end_header' line")
        words = line.decode("ascii", "replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            if not binary:
                raise InputError(path, "format", "PLY header has no 'format' line")
            return elements, handle.tell()
        if words[0] == "format":
            if words[1:2] != ["binary_little_endian"]:
                raise InputError(path, "format", f"expected binary_little_endian, found '{' '.join(words[1:])}'")
            binary = True
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and words[-1] in {n for n, _ in elements[-1][2]}:
            raise InputError(path, words[-1], f"property listed twice in element '{elements[-1][0]}'")
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in _PLY_TYPES:
            elements[-1][2].append((words[2], np.dtype("<" + _PLY_TYPES[words[1]])))
        elif words[0] == "property" and elements and words[1:2] == ["list"]:
            elements[-1][2].append((words[-1], None))
        else:
            raise InputError(path, None, f"unexpected PLY header line '{line.decode('ascii', 'replace').strip()}'")


def _vertex_table(path) -> np.ndarray:
    """The ``vertex`` element as a structured array (elements before it must have fixed-size rows)."""
    check_regular_file(path)
    try:
        with open(path, "rb") as handle:
            elements, offset = _read_header(path, handle)
            file_size = os.fstat(handle.fileno()).st_size
            for name, count, properties in elements:
                if any(kind is None for _, kind in properties):
                    if name == "vertex":
                        raise InputError(path, "vertex", "list properties are not part of a Gaussian PLY")
                    raise InputError(path, name, "a list element before 'vertex' is not supported")
                dtype = np.dtype([(prop, kind) for prop, kind in properties])
                if name == "vertex":
                    if count > MAX_PLY_VERTICES:
                        raise InputError(path, "vertex", f"declares {count} vertices (limit {MAX_PLY_VERTICES})")
                    if offset + dtype.itemsize * count > file_size:  # checked before reading anything
                        raise InputError(path, "vertex", f"file ends after {max(file_size - offset, 0)} of "
                                                         f"{dtype.itemsize * count} data bytes")
                    handle.seek(offset)
                    data = handle.read(dtype.itemsize * count)
                    if len(data) != dtype.itemsize * count:
                        raise InputError(path, "vertex", f"file ends after {len(data)} of {dtype.itemsize * count} data bytes")
                    return np.frombuffer(data, dtype=dtype, count=count)
                offset += dtype.itemsize * count
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    raise InputError(path, "vertex", "the PLY file has no 'vertex' element")


def read_gaussian_ply(path: str | os.PathLike) -> dict:
    """Read a 3DGS PLY into numpy arrays (float32; ``binding`` int64 or None).

    Returns ``means, scales_log, quats, opacity_logit, sh (N, K, 3), binding, sh_degree``,
    the same names as ``write_gaussian_ply`` takes. Properties are found by name, so
    extra ones are ignored; a missing one is an error that names it, and so is a file of no Gaussians.
    """
    table = _vertex_table(path)
    present = set(table.dtype.names)
    rest = sum(1 for n in present if n.startswith("f_rest_"))
    degree = _sh_degree(rest // 3 + 1) if rest % 3 == 0 else None
    if degree is None:
        raise InputError(path, "f_rest", f"{rest} f_rest properties is not 3 * ((d+1)^2 - 1) for any SH degree d")
    binding_name = next((n for n in ("binding_0", "binding") if n in present), None)
    for name in gaussian_property_names(degree):
        if name not in present:
            raise InputError(path, name, "missing property of the 3DGS Gaussian layout")
    if len(table) == 0:
        raise InputError(path, "vertex", "no Gaussians (0 vertices): expected at least one")

    def stack(names):
        return np.stack([table[n].astype(np.float32) for n in names], axis=1)

    count = len(table)
    coefficients = (degree + 1) ** 2
    sh = np.empty((count, coefficients, 3), dtype=np.float32)
    sh[:, 0, :] = stack(["f_dc_0", "f_dc_1", "f_dc_2"])
    if rest:
        sh[:, 1:, :] = stack([f"f_rest_{i}" for i in range(rest)]).reshape(count, 3, coefficients - 1).transpose(0, 2, 1)
    binding = None
    if binding_name is not None:
        raw = table[binding_name]
        finite = np.isfinite(raw) if raw.dtype.kind == "f" else np.ones(len(raw), bool)
        binding = np.where(finite, raw, -1).astype(np.int64)
        bad = (binding != raw) | (binding < 0) | (binding >= 2**31)
        if bad.any():  # GaussianAvatars writes the ids as floats: whole numbers are taken, others refused
            first = int(np.argmax(bad))
            raise InputError(path, binding_name, f"face ids must be non-negative integers; Gaussian {first} "
                                                 f"holds {raw[first]!r} (and {int(bad.sum()) - 1} more)")
    out = {
        "means": stack(["x", "y", "z"]),
        "scales_log": stack(["scale_0", "scale_1", "scale_2"]),
        "quats": stack(["rot_0", "rot_1", "rot_2", "rot_3"]),
        "opacity_logit": table["opacity"].astype(np.float32),
        "sh": sh,
    }
    for name, values in out.items():
        bad = ~np.isfinite(values.reshape(count, -1)).all(axis=1) if count else np.zeros(0, bool)
        if bad.any():
            raise InputError(path, name, f"Gaussian {int(np.argmax(bad))} (and {int(bad.sum()) - 1} more) "
                                         "holds NaN or infinite values")
    return {**out, "binding": binding, "sh_degree": degree}
