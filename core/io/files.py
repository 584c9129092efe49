"""Checks on the files and names that inputs point at, shared by every reader and writer.

Readers accept regular files only (a FIFO or device would block ``open`` or stream forever);
names that become file names (camera ids) must be plain names; references from one file to
another (a capture's ``model_file``, an avatar's ``head_file``) must stay inside their folder.
"""

from __future__ import annotations

import os
import pathlib
import re
import stat

from ..errors import InputError

_PLAIN = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.+-]{0,127}$")
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def check_path_text(value, source, field: str, error: type[InputError] = InputError) -> str:
    """A path read from a file: a non-empty string without NUL or other control characters (the
    system cannot take a NUL; a newline or escape in a name forges lines in logs and terminals)."""
    if not isinstance(value, str) or not value:
        raise error(source, field, f"expected a non-empty path string, got {value!r}")
    bad = _CONTROL.search(value)
    if bad:
        raise error(source, field, f"control character {bad.group()!r} in the path {value!r}")
    return value


def check_regular_file(path: str | os.PathLike, error: type[InputError] = InputError) -> None:
    """Refuse anything but an existing regular file, without ever blocking on it."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise error(path, None, "file not found") from None
    except IsADirectoryError:
        raise error(path, None, "expected a file, found a folder") from None
    except OSError as problem:
        raise error(path, None, f"cannot open ({problem.strerror})") from None
    try:
        mode = os.fstat(fd).st_mode
    finally:
        os.close(fd)
    if stat.S_ISDIR(mode):
        raise error(path, None, "expected a file, found a folder")
    if not stat.S_ISREG(mode):
        raise error(path, None, "expected a regular file (found a pipe, socket or device)")


def check_plain_name(value, source, field: str, error: type[InputError] = InputError) -> str:
    """A name that is safe as a file name on every system: letters, digits, ``_ . + -``, not
    starting with a dot or dash, at most 128 characters (so ``../x`` or ``C:x`` never are)."""
    if not isinstance(value, str) or not _PLAIN.match(value) or value in (".", ".."):
        raise error(source, field, f"expected a plain name (letters, digits, '_', '.', '+', '-'; "
                                   f"no folders), got {value!r}")
    return value


def file_inside(folder: str | os.PathLike, reference, source, field: str,
                error: type[InputError] = InputError) -> pathlib.Path:
    """``folder / reference`` for a relative reference that stays inside ``folder`` (in text and
    after resolving links)."""
    check_path_text(reference, source, field, error)
    if "\\" in reference:
        raise error(source, field, f"expected a relative file name, got {reference!r}")
    relative = pathlib.PurePosixPath(reference)
    if relative.is_absolute() or ".." in relative.parts or re.match(r"^[A-Za-z]:", reference):
        raise error(source, field, f"expected a file inside {folder}, got {reference!r}")
    folder = pathlib.Path(folder)
    path = folder.joinpath(*relative.parts)
    real_folder = folder.resolve()
    if not path.resolve().is_relative_to(real_folder):
        raise error(source, field, f"{reference!r} leads outside {folder}")
    return path
