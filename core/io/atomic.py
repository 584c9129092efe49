"""Write files so that a crash never leaves a half-written file at the final path, and an output
never replaces what is not a file.

Every output the project writes goes through here. A target that exists must be a regular file
(it is replaced) or a symbolic link to one (the link itself is replaced by the new file; the file
it pointed to is left as it was, so a link planted in a folder never redirects a write elsewhere).
A device, FIFO, socket or folder at the target, or a link to one, is refused: renaming over it
would replace a device node as root, and writing into it is not what an output path means.
"""

from __future__ import annotations

import contextlib
import errno
import os
import pathlib
import stat
import tempfile
import threading

from ..errors import InputError

_umask_lock = threading.Lock()
# what writing to a file may fail with, naming no file (a write to an open handle)
_WRITE_ERRORS = {errno.ENOSPC, errno.EROFS, errno.EFBIG, getattr(errno, "EDQUOT", errno.ENOSPC)}


def current_umask() -> int:
    """The process's umask (read by setting it and putting it back, under a lock)."""
    with _umask_lock:
        mask = os.umask(0o077)
        os.umask(mask)
    return mask


def _usual_permissions(path) -> None:
    """Give a ``mkstemp`` file (always 0600) the mode ``open`` would have given: 0666 less the umask."""
    os.chmod(path, 0o666 & ~current_umask())


def kind_of(mode: int) -> str:
    """What a file of ``st_mode`` is, in words (for messages)."""
    for test, name in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISLNK, "a symbolic link")):
        if test(mode):
            return name
    return "not a regular file"


def check_output_target(path: str | os.PathLike, folder: bool = False) -> None:
    """Refuse an output path where something other than a regular file (or a link to one) exists;
    with ``folder``, an output folder (``--out DIR``, a run folder): a folder or a link to one.

    Absent targets are fine, and so are dangling links to a file (replaced, never followed).
    """
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as problem:
        if problem.errno == errno.ENOTDIR:
            _refuse_what_is_not_a_folder_above(path)
        raise InputError(path, None, f"cannot be written ({problem.strerror})") from None
    wanted = stat.S_ISDIR if folder else stat.S_ISREG
    expected = ("expected a folder for the outputs (or a path that does not exist yet): choose another output "
                "folder") if folder else "an output replaces a regular file only: choose another output path"
    if wanted(mode):
        return
    if stat.S_ISLNK(mode):
        try:
            target = os.stat(path).st_mode
        except OSError:  # dangling or looping: the link alone is replaced
            if not folder:
                return
            raise InputError(path, None, f"is a symbolic link that leads nowhere ({os.readlink(path)}); "
                                         f"{expected}") from None
        if wanted(target):
            return
        raise InputError(path, None, f"is a symbolic link to {kind_of(target)} ({os.readlink(path)}); {expected}")
    raise InputError(path, None, f"is {kind_of(mode)}; {expected}")


def _refuse_what_is_not_a_folder_above(path) -> None:
    """Name the file (FIFO, device) on the way to ``path`` that stands where a folder is needed."""
    for parent in pathlib.Path(path).parents:
        try:
            mode = os.stat(parent).st_mode
        except OSError:
            continue
        if not stat.S_ISDIR(mode):
            raise InputError(parent, None, f"is {kind_of(mode)}, where a folder is needed to hold {path}: choose "
                                           f"another output path")
        return


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success.

    The temporary name keeps the final suffix, so writers that pick a format by
    extension (PIL, OpenEXR, numpy) behave as they would for ``path`` itself. The target is
    checked before anything is written and again just before the rename. An error that names
    the temporary file, or a full disk's that names none, is raised naming ``path``: the temporary
    is gone by then.
    """
    path = pathlib.Path(path)
    check_output_target(path)  # also names a file on the way that stands where a folder is needed
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".partial{path.suffix}", dir=path.parent)
    os.close(fd)
    try:
        _usual_permissions(tmp)
        yield pathlib.Path(tmp)
        check_output_target(path)
        os.replace(tmp, path)
    except BaseException as error:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(error, InputError) and error.path == tmp:
            raise type(error)(path, error.field, error.problem.replace(tmp, str(path))) from None
        if isinstance(error, OSError) and error.errno is not None and (
                error.filename == tmp or (error.filename is None and error.errno in _WRITE_ERRORS)):
            raise OSError(error.errno, error.strerror, str(path)) from None
        raise


def remove_partials(folder: str | os.PathLike) -> list[pathlib.Path]:
    """Delete the temporary files a killed writer of :func:`atomic_path` left in ``folder`` (``.*.partial*``)."""
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        return []
    removed = [p for p in folder.iterdir() if p.name.startswith(".") and ".partial" in p.name and p.is_file()]
    for p in removed:
        p.unlink(missing_ok=True)
    return removed


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb", **kwargs):
    """``open`` for writing, atomically: the file appears at ``path`` complete or not at all."""
    with atomic_path(path) as tmp:
        with open(tmp, mode, **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())


def open_for_append(path: str | os.PathLike, encoding: str = "utf-8"):
    """Open a log for appending (a log grows, so it cannot be written atomically): the target must be
    absent or a regular file, and a link is never followed (a planted link could append elsewhere)."""
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    check_output_target(path)
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as problem:
        if os.path.islink(path):
            raise InputError(path, None, "is a symbolic link; a log is appended to a regular file only") from None
        raise InputError(path, None, f"cannot be written ({problem.strerror})") from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise InputError(path, None, f"is {kind_of(mode)}; a log is appended to a regular file only")
    if hasattr(os, "set_blocking"):
        os.set_blocking(fd, True)
    return open(fd, "a", encoding=encoding)


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 text atomically."""
    with atomic_open(path, "w", encoding="utf-8", newline="\n") as handle:
        handle.write(text)


def write_json(path: str | os.PathLike, obj, *, indent: int | None = 2) -> None:
    """Write ``obj`` as JSON atomically; NaN and inf are refused (they are not JSON)."""
    import json

    write_text(path, json.dumps(obj, indent=indent, allow_nan=False) + "\n")
