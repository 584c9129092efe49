"""One writer per run folder: an advisory lock on ``RUN/.lock`` that holds the owner's pid.

The operating system drops the lock when its process ends, however it ends, so a lock left by a
killed run is stale by construction: the next writer takes it (and says whose it was). A second
live writer is refused with the owner's pid.
"""

from __future__ import annotations

import os
import pathlib

from ..errors import InputError
from ..run.names import CHECKPOINT_DIR, LOCK_FILE

try:
    import fcntl

    def _try_lock(fd: int) -> bool:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            return False

except ImportError:  # Windows
    import msvcrt

    def _try_lock(fd: int) -> bool:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
            return True
        except OSError:
            return False


class RunLock:
    """Hold the run folder's lock; ``previous_owner`` is the pid of a stale lock taken over."""

    def __init__(self, root: str | os.PathLike):
        self.path = pathlib.Path(root) / LOCK_FILE
        self.previous_owner: int | None = None
        self.removed_partials: list[pathlib.Path] = []
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> "RunLock":
        if self._fd is not None:
            return self
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:
            raise InputError(self.path.parent, None, f"cannot write the run folder ({error.strerror})") from None
        owner = _read_pid(fd)
        if not _try_lock(fd):
            os.close(fd)
            who = f"pid {owner}" if owner else "another process"
            raise InputError(self.path.parent, None, f"in use by another training process ({who}); wait for it "
                                                     "to finish or stop it, or choose another folder")
        self.previous_owner = owner if owner and owner != os.getpid() else None
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.ftruncate(fd, 0)
            os.close(fd)  # closing drops the lock

    def __del__(self):
        self.release()

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()


def _read_pid(fd: int) -> int | None:
    os.lseek(fd, 0, os.SEEK_SET)
    text = os.read(fd, 32).decode("ascii", "replace").strip()
    return int(text) if text.isdigit() else None


def take_run_folder(root: pathlib.Path) -> RunLock:
    """Create ``root`` if needed and hold its lock; then clear what killed writers left there."""
    from ..io.atomic import check_output_target, remove_partials

    check_output_target(root, folder=True)  # a FIFO, device or file there: say what it is
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(root, None, f"cannot create the run folder ({error.strerror})") from None
    lock = RunLock(root).acquire()
    lock.removed_partials = remove_partials(root / CHECKPOINT_DIR) + remove_partials(root)
    return lock
