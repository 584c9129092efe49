"""Where the files a capture names may lie: the one rule, applied to every referenced file.

A capture folder names its images, masks and FLAME files by relative paths. Two forms are
accepted:

- ``images/00000_00.png``: inside the capture folder;
- ``../SEQUENCE/images/00000_00.png``: inside a sibling folder of the capture, the form
  VHAP's ``combine_nerf_datasets.py`` writes for union datasets (every sequence folder and
  the union folder share one parent). ``..`` may only be the first component and must be
  followed by a plain folder name.

Absolute paths, drive letters and any other ``..`` are refused on the text. Then the rule
for links: the path with every symlink followed must stay inside the *allowed tree*: the
capture folder for the first form, the capture's parent folder for the second (both with
their own symlinks followed). So a symlinked folder that points elsewhere inside the tree
is fine, one that points out of it is refused, for every file a capture names.
"""

from __future__ import annotations

import os
import pathlib
import posixpath

from ..errors import CaptureError
from ..io.files import check_path_text


def split_relative(relative, source, field: str) -> tuple[bool, list[str]]:
    """``(is_sibling, parts)`` of a capture-relative path, refusing the forms that may leave it."""
    check_path_text(relative, source, field, CaptureError)
    text = relative.replace("\\", "/")
    parts = [p for p in text.split("/") if p not in ("", ".")]
    if posixpath.isabs(text) or (len(text) >= 2 and text[1] == ":"):
        raise CaptureError(source, field, f"absolute path {relative!r}: paths must be relative to the dataset folder")
    sibling = bool(parts) and parts[0] == ".."
    rest = parts[1:] if sibling else parts
    if ".." in rest or not rest or (sibling and len(rest) < 2):
        raise CaptureError(
            source, field,
            f"path {relative!r} leaves the dataset folder (allowed: 'a/b.png' inside it, or "
            "'../SEQUENCE/a/b.png' into a sibling sequence folder of a union dataset)",
        )
    return sibling, rest


def resolve_capture_path(root: pathlib.Path, relative, source, field: str) -> pathlib.Path:
    """The absolute path of a file a capture names, checked on the text (no file access)."""
    sibling, parts = split_relative(relative, source, field)
    base = root.parent if sibling else root
    return base.joinpath(*parts)


def allowed_tree(root: pathlib.Path, relative: str) -> pathlib.Path:
    """The folder the real file of ``relative`` must lie in (links followed)."""
    sibling, _ = split_relative(relative, None, "path")
    base = pathlib.Path(root).absolute()
    return pathlib.Path(os.path.realpath(base.parent if sibling else base))


def check_stays_inside(root: pathlib.Path, relative: str, path: pathlib.Path, source, field: str) -> pathlib.Path:
    """``path`` if, with every symlink followed, it stays in its allowed tree; else a CaptureError."""
    tree = allowed_tree(root, relative)
    real = pathlib.Path(os.path.realpath(path))
    if real != tree and tree not in real.parents:
        raise CaptureError(
            source, field,
            f"{relative!r} leads to {real} through a symbolic link, outside {tree}; "
            "copy the files into the dataset instead of linking out of it",
        )
    return path
