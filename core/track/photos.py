"""Photos (JPEG, PNG), a folder's or a list of files: their headers (size, EXIF orientation and
lens) read before any is decoded, then each decoded upright (:mod:`.decode` says what a frame and
an input are)."""

from __future__ import annotations

import os
import pathlib
import re
from collections.abc import Iterator

import numpy as np

from ..errors import InputError
from ..io.files import check_regular_file
from ..limits import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE
from .inputs import (
    ORIENTATION_NAMES,
    PHOTO_SUFFIXES,
    UNSUPPORTED_PHOTO_SUFFIXES,
    FootageInfo,
    Frame,
    FrameSelection,
    PhotoInfo,
    check_size_option,
    check_threads,
    output_size,
    swaps_sides,
    upright,
)

EXIF_IFD = 0x8769
EXIF_ORIENTATION = 0x0112
EXIF_FOCAL_35MM = 0xA405  # FocalLengthIn35mmFilm


def _natural_key(name: str):
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def check_photo_size(path, width: int, height: int) -> None:
    if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE and width * height <= MAX_IMAGE_PIXELS):
        raise InputError(path, "size", f"declares {width}x{height} pixels; the limit is {MAX_IMAGE_SIDE} a side and "
                                       f"{MAX_IMAGE_PIXELS} in all")


def _photo_header(path: pathlib.Path) -> PhotoInfo:
    from PIL import Image

    check_regular_file(path)
    try:
        with Image.open(path) as image:
            width, height = image.size
            check_photo_size(path, width, height)
            exif = image.getexif()
            orientation = int(exif.get(EXIF_ORIENTATION, 1) or 1)
            focal = exif.get_ifd(EXIF_IFD).get(EXIF_FOCAL_35MM)
            kind = image.format or "?"
    except InputError:
        raise
    except Exception as error:  # pillow raises many types for what is not an image
        raise InputError(path, None, f"not a photo that can be read ({error}); expected a JPEG or PNG") from None
    if kind not in ("JPEG", "PNG", "MPO"):
        raise InputError(path, None, f"is a {kind} image; expected a JPEG or PNG photo")
    if orientation not in ORIENTATION_NAMES:
        raise InputError(path, "Orientation", f"expected an EXIF orientation 1 to 8, got {orientation}")
    try:
        focal = float(focal) if focal else None
    except (TypeError, ValueError):
        focal = None
    if swaps_sides(orientation):
        width, height = height, width
    return PhotoInfo(path.name, width, height, orientation, focal, "JPEG" if kind == "MPO" else kind)


class Photos:
    """Photos (JPEG, PNG): a folder's, in natural name order, or a list of files."""

    kind = "photos"

    def __init__(self, source: str | os.PathLike | list):
        if isinstance(source, list | tuple):
            paths = [pathlib.Path(p) for p in source]
            if not paths:
                raise InputError(None, None, "no photos given")
            self.path = paths[0] if len(paths) == 1 else paths[0].parent
            ignored = []
        else:
            self.path = pathlib.Path(source)
            paths, ignored = self._listing(self.path)
        self.paths = paths
        headers = tuple(_photo_header(p) for p in paths)
        formats = sorted({h.format.lower() for h in headers})
        focals = {h.focal_35mm for h in headers}
        first = headers[0]
        self.info = FootageInfo(
            path=self.path, kind="photos", frame_count=len(headers), frame_count_exact=True, fps=None,
            width=first.width, height=first.height, codec="+".join(formats), duration=None,
            focal_35mm=focals.pop() if len(focals) == 1 else None, photos=headers, ignored=tuple(ignored),
        )

    @staticmethod
    def _listing(folder: pathlib.Path) -> tuple[list[pathlib.Path], list[str]]:
        if not folder.is_dir():
            raise InputError(folder, None, "expected a video file or a folder of photos")
        photos, ignored = [], []
        try:
            entries = sorted(os.scandir(folder), key=lambda e: _natural_key(e.name))
        except OSError as error:
            raise InputError(folder, None, f"cannot be listed ({error.strerror})") from None
        for entry in entries:
            if entry.name.startswith("."):  # hidden files, and macOS's ._NAME companions
                continue
            suffix = pathlib.Path(entry.name).suffix.lower()
            if suffix in UNSUPPORTED_PHOTO_SUFFIXES:
                raise InputError(entry.path, None, f"{UNSUPPORTED_PHOTO_SUFFIXES[suffix]} photos cannot be read; "
                                                   f"expected JPEG or PNG (export them as JPEG; on an iPhone, "
                                                   f"Settings > Camera > Formats > Most Compatible)")
            if suffix in PHOTO_SUFFIXES and not entry.is_dir():
                photos.append(pathlib.Path(entry.path))
            else:
                ignored.append(entry.name)
        if not photos:
            raise InputError(folder, None, f"holds no photos; expected JPEG or PNG files "
                                           f"({', '.join(PHOTO_SUFFIXES)})")
        return photos, ignored

    def frames(self, selection: FrameSelection = FrameSelection(), size: int | None = None,
               threads: int | None = None) -> Iterator[Frame]:
        """Decode the selected photos, upright, as RGB ``uint8``; the longer side ``size`` if given.
        Photos have no time: a selection in seconds or by rate is refused. ``threads`` is unused."""
        selection.check(self.path)
        check_size_option(size, self.path)
        check_threads(threads, self.path)
        if selection.uses_time:
            raise InputError(self.path, "fps" if selection.fps is not None else "start_time",
                             "photos have no time: select them by frame number (start, end, stride)")
        pick = selection.picker()
        for index, (path, header) in enumerate(zip(self.paths, self.info.photos)):
            choice = pick(index, None)
            if choice == "stop":
                break
            if choice == "take":
                yield Frame(index, None, read_photo(path, header, size))


def read_photo(path, header: PhotoInfo, size: int | None = None) -> np.ndarray:
    """One photo as upright RGB ``uint8``, the longer side ``size`` if given (JPEGs are decoded at a
    reduced scale first where that is enough: pillow's draft mode)."""
    from PIL import Image

    out_w, out_h = output_size(header.width, header.height, size)
    stored = (out_h, out_w) if swaps_sides(header.orientation) else (out_w, out_h)
    try:
        with Image.open(path) as image:
            if size is not None and image.format == "JPEG":
                image.draft("RGB", stored)
            image.load()
            if image.mode in ("I;16", "I;16B", "I;16L", "I"):
                array = np.asarray(image).astype(np.float64)
                scale = 65535.0 if array.max(initial=0) > 255 else 255.0
                image = Image.fromarray((np.clip(array / scale, 0, 1) * 255 + 0.5).astype(np.uint8), "L")
            image = image.convert("RGB")
            if image.size != stored:
                image = image.resize(stored, Image.Resampling.LANCZOS if size is not None else Image.Resampling.BILINEAR,
                                     reducing_gap=3.0)
            array = np.asarray(image)
    except Exception as error:
        raise InputError(path, None, f"the photo cannot be decoded ({error})") from None
    return upright(array, header.orientation)
