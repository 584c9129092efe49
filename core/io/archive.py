"""Zip archives (``.npz``, torch files): how many members one declares, read from its end record
before :mod:`zipfile` builds an entry object for each (~500 bytes a member: 91 MB of empty
members became 0.5 GB)."""

from __future__ import annotations

import os
import zipfile

from ..errors import InputError


def check_member_count(path: str | os.PathLike, limit: int, what: str) -> None:
    """Refuse an archive whose end record declares more than ``limit`` members (reads a few kB);
    ``what`` names the kind of archive with its article ("an .npz (zip) archive")."""
    try:
        with open(path, "rb") as handle:
            end = zipfile._EndRecData(handle)  # the standard library's own reader of the end record
    except OSError as error:
        raise InputError(path, None, f"unreadable {what} ({error.strerror})") from None
    if end is None:
        raise InputError(path, None, f"not {what}: no zip end record (truncated, or another kind of file)")
    count = end[zipfile._ECD_ENTRIES_TOTAL]
    if count > limit:
        raise InputError(path, None, f"declares {count} zip members; the limit is {limit} (see docs/safety.md)")
