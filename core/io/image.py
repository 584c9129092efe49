"""The project's one image loader and writers: PNG/JPEG through pillow, EXR through OpenEXR.

In memory an image is float32, HWC, values in [0, 1] for 8/16-bit formats (sRGB values, as
stored) and as stored for EXR (linear by convention). Every write is atomic.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ..errors import InputError
from ..limits import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE
from .atomic import atomic_path
from .files import check_regular_file

_EXR = ".exr"


def _is_exr(path) -> bool:
    return pathlib.Path(path).suffix.lower() == _EXR


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0,1] -> linear light (the IEC 61966-2-1 curve)."""
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear light -> sRGB-encoded values, clipped to [0,1]."""
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * x ** (1 / 2.4) - 0.055).astype(np.float32)


def check_image_size(path, width: int, height: int) -> None:
    """Refuse an image whose header declares more pixels than the limits (decompression bombs)."""
    if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE and width * height <= MAX_IMAGE_PIXELS):
        raise InputError(path, None, f"declares {width}x{height} pixels; the limit is {MAX_IMAGE_SIDE} "
                                     f"a side and {MAX_IMAGE_PIXELS} in all")


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(width, height)`` of an image file, read from its header only (no pixel decoding)."""
    check_regular_file(path)
    try:
        if _is_exr(path):
            import OpenEXR

            window = OpenEXR.File(os.fspath(path), header_only=True).header()["dataWindow"]
            return int(window[1][0] - window[0][0] + 1), int(window[1][1] - window[0][1] + 1)
        from PIL import Image

        with Image.open(path) as im:
            return im.size
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except Exception as error:  # pillow/OpenEXR raise many types for corrupt headers
        raise InputError(path, None, f"unreadable image header ({error})") from None


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Decode an image to float32 ``(H, W, C)``, ``C`` in {1, 2, 3, 4} (grey, grey+alpha, RGB, RGBA).

    8-bit and 16-bit images are scaled to [0, 1]; palette images are expanded; EXR channels
    are read as stored (R, G, B, A in that order; Y for single-channel files).
    """
    width, height = image_size(path)
    check_image_size(path, width, height)
    if _is_exr(path):
        return _read_exr(path)
    from PIL import Image

    try:
        with Image.open(path) as im:
            im.load()
            if im.mode == "P":
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
            elif im.mode == "1":
                im = im.convert("L")
            elif im.mode not in ("L", "LA", "RGB", "RGBA", "I", "I;16", "I;16B", "F"):
                im = im.convert("RGB")
            array = np.asarray(im)
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except Exception as error:
        raise InputError(path, None, f"unreadable image ({error})") from None
    if array.dtype == np.uint8:
        out = array.astype(np.float32) / 255.0
    elif array.dtype.kind in "ui" and array.dtype.itemsize >= 2:
        out = array.astype(np.float32) / 65535.0  # 16-bit PNG
    else:
        out = array.astype(np.float32)
    return out[..., None] if out.ndim == 2 else out


def _read_exr(path) -> np.ndarray:
    import OpenEXR

    try:
        channels = OpenEXR.File(os.fspath(path), separate_channels=True).channels()
    except Exception as error:
        if not os.path.exists(path):
            raise InputError(path, None, "file not found") from None
        raise InputError(path, None, f"unreadable EXR file ({error})") from None
    order = [c for c in ("R", "G", "B", "A") if c in channels] or [c for c in ("Y", "A") if c in channels]
    if not order:
        raise InputError(path, None, f"no R/G/B/A or Y channels (has {sorted(channels)})")
    return np.stack([np.asarray(channels[c].pixels, dtype=np.float32) for c in order], axis=-1)


def _as_hwc(image, path) -> np.ndarray:
    array = np.asarray(image)
    if array.ndim == 2:
        array = array[..., None]
    if array.ndim != 3 or array.shape[2] not in (1, 2, 3, 4) or array.shape[0] == 0 or array.shape[1] == 0:
        raise InputError(path, None, f"expected an (H,W) or (H,W,C) image with C in 1..4, got {array.shape}")
    return array


def to_uint8(image) -> np.ndarray:
    """Float values in [0,1] -> uint8 (clipped, rounded to nearest); uint8 passes through."""
    array = np.asarray(image)
    if array.dtype == np.uint8:
        return array
    return (np.clip(np.nan_to_num(array.astype(np.float32)), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_png(path: str | os.PathLike, image, *, compress_level: int = 4) -> None:
    """Write an 8-bit PNG atomically from float [0,1] (sRGB values) or uint8, HW or HWC."""
    from PIL import Image

    array = to_uint8(_as_hwc(image, path))
    mode = {1: "L", 2: "LA", 3: "RGB", 4: "RGBA"}[array.shape[2]]
    pil = Image.fromarray(array[..., 0] if mode == "L" else array, mode)
    with atomic_path(path) as tmp:
        pil.save(tmp, format="PNG", compress_level=compress_level)


def write_exr(path: str | os.PathLike, rgb, alpha=None, *, half: bool = False) -> None:
    """Write an RGBA (or RGB when ``alpha`` is None) EXR atomically, float32 or half.

    Values are stored as given; Blender and compositors read EXR as linear light, so convert
    sRGB images with :func:`srgb_to_linear` first when that is what they hold.
    """
    import OpenEXR

    rgb = _as_hwc(rgb, path)
    if rgb.shape[2] != 3:
        raise InputError(path, "rgb", f"expected (H,W,3), got {rgb.shape}")
    dtype = np.float16 if half else np.float32
    channels = {name: np.ascontiguousarray(rgb[..., k], dtype=dtype) for k, name in enumerate("RGB")}
    if alpha is not None:
        alpha = np.asarray(alpha)
        if alpha.shape not in (rgb.shape[:2], rgb.shape[:2] + (1,)):
            raise InputError(path, "alpha", f"expected shape {rgb.shape[:2]}, got {alpha.shape}")
        channels["A"] = np.ascontiguousarray(alpha.reshape(rgb.shape[:2]), dtype=dtype)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp:
        try:
            OpenEXR.File(header, channels).write(os.fspath(tmp))
        except RuntimeError as error:  # OpenEXR's form of a full or read-only disk
            raise InputError(tmp, None, f"cannot write (disk full or not writable? {error})") from None
