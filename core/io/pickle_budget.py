"""Bounds on what a pickle may build, so a tiny file cannot grow without limit.

A pickle of a few bytes can reference one container from many places (memo GET, DUP):
``x = (x, x)`` thirty times is 60 bytes, and whatever walks it as a tree (``numpy.asarray``,
``numpy.dtype``, ``repr``) visits 2³⁰ leaves. So the restricted unpickler

- first walks the opcodes without building anything (:func:`scan_opcodes`): at most
  :func:`object_budget` of them, memo slots numbered as a pickler numbers them (an unpickler
  keeps its memo as an array as long as the largest slot), declared lengths within the file;
- then measures every argument numpy is asked to walk, and the loaded result, with shared
  containers counted each time they are reached (:class:`ObjectBudget`), before anything walks
  them as a tree.
"""

from __future__ import annotations

import contextlib
import io
import mmap
import pickle
import pickletools
import reprlib
import types

import numpy as np

from ..errors import UnsafePickleError
from ..limits import MAX_PICKLE_DEPTH, MAX_PICKLE_OBJECTS, PICKLE_OBJECTS_PER_BYTE

_MEMO_PUTS = ("PUT", "BINPUT", "LONG_BINPUT")
_SHORT = reprlib.Repr()
_SHORT.maxlevel, _SHORT.maxtuple, _SHORT.maxlist, _SHORT.maxdict, _SHORT.maxother = 3, 6, 6, 4, 60


def short_repr(value) -> str:
    """A repr of bounded length whatever ``value`` holds (for error messages)."""
    return _SHORT.repr(value)


def object_budget(file_bytes: int) -> int:
    """How many objects a pickle of ``file_bytes`` may build: a few per byte, at most the cap."""
    return min(MAX_PICKLE_OBJECTS, PICKLE_OBJECTS_PER_BYTE * file_bytes + 4096)


def scan_opcodes(handle, path, budget: int, offset: int = 0) -> None:
    """Walk the pickle's opcodes (nothing is built) and refuse what the unpickler must not see.

    Refusals are :class:`UnsafePickleError`; a damaged pickle is ``pickle.UnpicklingError``.
    ``handle`` is a file opened for binary reading whose pickle starts at byte ``offset`` (after a
    ``.npy`` header, say); it is left there.
    """
    size = _file_size(handle)
    if size <= offset:
        raise pickle.UnpicklingError("empty file" if offset == 0 else f"nothing after byte {offset}")
    with _view(handle) as view:  # read(n) never allocates n
        view.seek(offset)
        count = 0
        try:
            for opcode, arg, position in pickletools.genops(view):
                count += 1
                if count > budget:
                    raise UnsafePickleError(path, None, f"more than {budget} pickle operations (the limit for "
                                                        f"a file of {size} bytes; see docs/safety.md)")
                if opcode.name in _MEMO_PUTS and not 0 <= arg < count:
                    raise UnsafePickleError(path, None, f"memo slot {arg} at byte {position} is out of order "
                                                        f"(a pickler numbers its slots 0, 1, 2, ...)")
                if opcode.name == "FRAME" and arg > size - position:
                    raise UnsafePickleError(path, None, f"frame of {arg} bytes at byte {position} runs past the "
                                                        f"end of the file")
        except UnsafePickleError:
            raise
        except ValueError as error:  # truncated data, unknown opcode, bad argument: for the caller to word
            raise pickle.UnpicklingError(str(error)) from None
    handle.seek(offset)


def _view(handle):
    """A file's bytes as a read-only map, or an in-memory buffer (a pickle read out of an archive) as is."""
    if isinstance(handle, io.BytesIO):
        return contextlib.nullcontext(io.BytesIO(handle.getbuffer()))
    return mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)


def _file_size(handle) -> int:
    handle.seek(0, 2)
    size = handle.tell()
    handle.seek(0)
    return size


class ObjectBudget:
    """Counts the objects of what numpy or a caller will walk as a tree, before it does.

    ``settle(obj)`` measures ``obj`` (shared containers counted every time they are reached,
    at most ``budget`` in all; at most ``MAX_PICKLE_DEPTH`` deep; no cycles) and returns it
    with each object ``convert`` maps replaced, sharing kept. The work of all walks together
    is bounded by the budget too, so many calls over one shared structure stay cheap.
    """

    def __init__(self, path, budget: int, convert=None):
        self.path = path
        self.budget = budget
        self.work = 0
        self._convert = convert or (lambda obj: obj)

    def settle(self, obj, what: str = "the pickle"):
        done: dict[int, tuple[object, int]] = {}
        settled, _ = self._walk(obj, done, set(), 0, what)
        return settled

    def _refuse(self, what, problem):
        raise UnsafePickleError(self.path, None, f"refused {what}: {problem} (see docs/safety.md)")

    def _walk(self, obj, done, active, depth, what):
        key = id(obj)
        if key in done:
            return done[key]
        children = _children(obj)
        if children is None:
            done[key] = (self._convert(obj), 1)  # one conversion for every reference: sharing is kept
            return done[key]
        if key in active:
            self._refuse(what, "it contains itself")
        if depth >= MAX_PICKLE_DEPTH:
            self._refuse(what, f"nested more than {MAX_PICKLE_DEPTH} deep")
        self.work += 1
        if self.work > self.budget:
            self._refuse(what, f"more than {self.budget} objects to walk in all; the limit for a file "
                                   f"of this size")
        active.add(key)
        total, settled_children = 1, []
        for child in children:
            settled, count = self._walk(child, done, active, depth + 1, what)
            total += count
            if total > self.budget:
                self._refuse(what, f"it holds more than {self.budget} objects, counting a shared one each time it "
                                   f"is reached; the limit for a file of this size")
            settled_children.append(settled)
        active.discard(key)
        done[key] = (_rebuilt(obj, settled_children, self._convert), total)
        return done[key]


def _children(obj):
    """The objects inside a container (None for a leaf), in the order ``_rebuilt`` expects."""
    if isinstance(obj, (list, tuple, set, frozenset)):
        return list(obj)
    if isinstance(obj, dict):
        return [part for item in obj.items() for part in item]
    if isinstance(obj, np.ndarray):
        return list(obj.flat) if obj.dtype.hasobject else None
    state = getattr(obj, "__dict__", None)
    if isinstance(state, dict) and not isinstance(obj, (type, types.FunctionType, types.MethodType)):
        return list(state.values())
    return None


def _rebuilt(obj, children, convert):
    """``obj`` holding ``children`` (containers rebuilt, arrays and stand-ins updated in place)."""
    if isinstance(obj, list):
        return children
    if isinstance(obj, tuple):
        return tuple(children)
    if isinstance(obj, (set, frozenset)):
        return type(obj)(children)
    if isinstance(obj, dict):
        return dict(zip(children[0::2], children[1::2]))
    if isinstance(obj, np.ndarray):
        for index, child in enumerate(children):
            obj.flat[index] = child
        return convert(obj)
    obj.__dict__.update(zip(list(obj.__dict__), children))
    return obj
