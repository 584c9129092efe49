"""Ways to break a copy of a valid capture, run, head model or PLY: each writes one hostile file."""

import io
import json
import pickle
import struct
import zipfile
import zlib

import numpy as np


def edit_json(path, change):
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def set_first_frame(capture, **values):
    edit_json(capture / "transforms_train.json", lambda d: [d["frames"][0].update(values)])


def set_every_frame(capture, **values):
    for split in ("train", "val", "test"):
        edit_json(capture / f"transforms_{split}.json", lambda d: [f.update(values) for f in d["frames"]])


def png_header_only(path, width, height):
    """A valid PNG signature and IHDR declaring ``width x height``, then one empty IDAT and IEND."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b""))
                     + chunk(b"IEND", b""))


def truncate(path, keep=0.5):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def npz_declaring(path, name, shape, dtype="<f4", payload=b""):
    """An .npz whose member's .npy header declares ``shape`` (the data may be far shorter)."""
    header = {"descr": dtype, "fortran_order": False, "shape": tuple(shape)}
    text = repr(header).encode("latin1")
    pad = 64 - (10 + len(text) + 1) % 64
    npy = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text) + pad + 1) + text + b" " * pad + b"\n" + payload
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(f"{name}.npy", npy)


def npz_inflating(path, name, megabytes):
    """A well-formed .npz whose one member inflates to ``megabytes`` of zeros (a few hundred kB on disk)."""
    buffer = io.BytesIO()
    np.save(buffer, np.zeros(megabytes * 2 ** 18, np.float32))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(f"{name}.npy", buffer.getvalue())


def nested_json(path, depth=100_000):
    path.write_text("[" * depth + "]" * depth)


class Reconstruct:
    """Pickles as numpy's array rebuilder asked for ``shape`` (it allocates before any data)."""

    def __init__(self, shape):
        self.shape = shape

    def __reduce__(self):
        from numpy.core.multiarray import _reconstruct

        return _reconstruct, (np.ndarray, self.shape, b"b")


def many_arrays(shape, times):
    """``times`` separate array rebuilds of ``shape``: each within the per-array limit, too many together."""
    return tuple(Reconstruct(shape) for _ in range(times))


def model_pickle(path, model):
    from mogaface.core.flame.safe_pickle import save_model_pickle

    save_model_pickle(path, model)


def raw_pickle(path, obj):
    with open(path, "wb") as handle:
        pickle.dump(obj, handle, protocol=2)


def codecs_encode_pickle(path, key="v_template", encoding=b"utf-8"):
    """A pickle whose value is ``_codecs.encode('x', encoding)`` (Python 3 pickles bytes with 'latin1')."""
    name = key.encode()
    path.write_bytes(pickle.PROTO + b"\x02" + pickle.EMPTY_DICT + pickle.SHORT_BINUNICODE + bytes([len(name)]) + name
                     + pickle.GLOBAL + b"_codecs\nencode\n" + pickle.SHORT_BINUNICODE + b"\x01x"
                     + pickle.SHORT_BINUNICODE + bytes([len(encoding)]) + encoding + pickle.TUPLE2 + pickle.REDUCE
                     + pickle.SETITEM + pickle.STOP)
    return path


def ply_with_header(path, lines, data=b""):
    path.write_bytes(("\n".join(["ply", "format binary_little_endian 1.0", *lines, "end_header"]) + "\n").encode()
                     + data)


def shared_reference_pickle(path, key="v_template", width=250, depth=4, chumpy=False):
    """A pickle of a few hundred bytes whose value is ``depth`` nested lists of ``width`` references
    to one list below (MARK, DUP and LIST opcodes): width ** depth elements once made an array."""
    body = pickle.MARK * depth + pickle.BINFLOAT + bytes(8) + (pickle.DUP * (width - 1) + pickle.LIST) * depth
    name = key.encode()
    value = body
    if chumpy:  # chumpy.ch.Ch() with state {'x': value}, as the official files store their arrays
        value = (pickle.GLOBAL + b"chumpy.ch\nCh\n" + pickle.EMPTY_TUPLE + pickle.NEWOBJ + pickle.EMPTY_DICT
                 + pickle.SHORT_BINUNICODE + b"\x01x" + body + pickle.SETITEM + pickle.BUILD)
    data = (pickle.PROTO + b"\x02" + pickle.EMPTY_DICT + pickle.SHORT_BINUNICODE + bytes([len(name)]) + name
            + value + pickle.SETITEM + pickle.STOP)
    path.write_bytes(data)
    return path


# -- torch files whose zip records or pickle declare what they do not hold ----------------------

def _zeros_deflated(nbytes, chunk=1 << 24):
    """Raw deflate of ``nbytes`` zeros, one compressed chunk repeated (a second for 2 GiB), and its CRC."""
    chunk = min(chunk, nbytes)
    assert nbytes % chunk == 0
    compressor = zlib.compressobj(9, zlib.DEFLATED, -15)
    piece = compressor.compress(bytes(chunk)) + compressor.flush(zlib.Z_FULL_FLUSH)  # byte-aligned, no history
    crc, zeros = 0, bytes(chunk)
    for _ in range(nbytes // chunk):
        crc = zlib.crc32(zeros, crc)
    return piece * (nbytes // chunk) + b"\x03\x00", crc  # + an empty final block


def write_zip(path, entries):
    """A zip of ``(name, data, method, crc, size)`` written by hand, so a record may claim any size."""
    out, central = bytearray(), bytearray()
    for name, data, method, crc, size in entries:
        encoded, offset = name.encode(), len(out)
        out += struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, method, 0, 0x21, crc, len(data), size,
                           len(encoded), 0) + encoded + data
        central += struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, method, 0, 0x21, crc, len(data), size,
                               len(encoded), 0, 0, 0, 0, 0, offset) + encoded
    out += central + struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(entries), len(entries), len(central), len(out), 0)
    path.write_bytes(bytes(out))


def torch_declaring(path, state, marker, declared, inflate=False, pickle_bytes=None):
    """``torch.save(state)`` rewritten: the count ``marker`` (>= 65536, found only where a tensor of
    that many elements is described) becomes ``declared`` in its pickle; with ``inflate`` the
    tensor's record becomes ``declared`` float32 zeros, deflated (a few MB for 2 GiB).
    ``pickle_bytes`` replaces the pickle instead."""
    import torch

    buffer = io.BytesIO()
    torch.save(state, buffer)
    entries = []
    with zipfile.ZipFile(buffer) as archive:
        for info in archive.infolist():
            data = archive.read(info)
            if info.filename.endswith("/data.pkl"):
                old, new = b"J" + struct.pack("<i", marker), b"J" + struct.pack("<i", declared)
                assert marker >= 65536 and old in data
                data = pickle_bytes if pickle_bytes is not None else data.replace(old, new)
            if inflate and info.file_size == 4 * marker:
                raw, crc = _zeros_deflated(4 * declared)
                entries.append((info.filename, raw, zipfile.ZIP_DEFLATED, crc, 4 * declared))
                continue
            entries.append((info.filename, data, zipfile.ZIP_STORED, zlib.crc32(data), len(data)))
    write_zip(path, entries)
    return path


class RunsCode:
    """Pickles as a call of ``os.system`` (what ``weights_only`` and our scan must refuse)."""

    def __reduce__(self):
        import os

        return os.system, ("echo ran > /dev/null",)


def avatar_with(run, tensor_name, make, **kwargs):
    """The run's avatar with one Gaussian tensor replaced by ``make()``'s marker tensor, declared by
    :func:`torch_declaring`'s ``kwargs``."""
    import torch

    state = torch.load(run / "avatar.pt", weights_only=True)
    state["gaussians"][tensor_name] = make()
    return torch_declaring(run / "avatar.pt", state, **kwargs)


def zip_of_empty_members(path, count):
    """A zip64 archive of ``count`` empty members (about 90 bytes each on disk; ~500 each once
    :mod:`zipfile` has built an entry object for every one)."""
    out, central = bytearray(), bytearray()
    for index in range(count):
        name, offset = f"{index}.npy".encode(), len(out)
        out += struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, 0, 0, 0x21, 0, 0, 0, len(name), 0) + name
        central += struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, 0, 0, 0x21, 0, 0, 0, len(name), 0, 0, 0, 0,
                               0, offset) + name
    start = len(out)
    out += central
    end64 = len(out)
    out += struct.pack("<IQHHIIQQQQ", 0x06064B50, 44, 45, 45, 0, 0, count, count, len(central), start)
    out += struct.pack("<IIQI", 0x07064B50, 0, end64, 1)
    out += struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, 0xFFFF, 0xFFFF, 0xFFFFFFFF, 0xFFFFFFFF, 0)
    path.write_bytes(bytes(out))
    return path
