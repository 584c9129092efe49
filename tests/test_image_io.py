"""The one image loader and the PNG/EXR writers."""

import numpy as np
import pytest
from PIL import Image

from mogaface.core.errors import InputError
from mogaface.core.io import image as imageio_


def test_png_round_trip_rgb_rgba_grey(tmp_path):
    rng = np.random.default_rng(0)
    for shape in [(5, 7, 3), (5, 7, 4), (5, 7), (5, 7, 1)]:
        data = rng.random(shape).astype(np.float32)
        path = tmp_path / f"img{len(shape)}_{shape[-1]}.png"
        imageio_.write_png(path, data)
        back = imageio_.read_image(path)
        expected = data if data.ndim == 3 else data[..., None]
        assert back.dtype == np.float32 and back.shape == expected.shape
        np.testing.assert_allclose(back, np.round(expected * 255) / 255, atol=1e-6)
        assert imageio_.image_size(path) == (7, 5)
    assert [p.name for p in tmp_path.iterdir() if "partial" in p.name] == []


def test_png_written_by_others_is_read(tmp_path):
    sixteen = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000)
    Image.fromarray(sixteen).save(tmp_path / "d16.png")
    back = imageio_.read_image(tmp_path / "d16.png")
    np.testing.assert_allclose(back[..., 0], sixteen / 65535.0, atol=1e-6)
    pal = Image.fromarray(np.array([[0, 1], [1, 0]], np.uint8), "P")
    pal.putpalette([255, 0, 0, 0, 0, 255] + [0] * 762)
    pal.save(tmp_path / "pal.png")
    np.testing.assert_allclose(imageio_.read_image(tmp_path / "pal.png")[0, 1], [0, 0, 1])


def test_exr_round_trip_checked_with_openexr_reader(tmp_path):
    import Imath
    import OpenEXR

    rng = np.random.default_rng(1)
    rgb = (rng.random((6, 9, 3)) * 4).astype(np.float32)  # HDR values survive
    alpha = rng.random((6, 9)).astype(np.float32)
    path = tmp_path / "frame.exr"
    imageio_.write_exr(path, rgb, alpha)
    legacy = OpenEXR.InputFile(str(path))
    header = legacy.header()
    assert set(header["channels"]) == {"R", "G", "B", "A"}
    window = header["dataWindow"]
    assert (window.max.x + 1, window.max.y + 1) == (9, 6)
    pt = Imath.PixelType(Imath.PixelType.FLOAT)
    for k, name in enumerate("RGBA"):
        plane = np.frombuffer(legacy.channel(name, pt), np.float32).reshape(6, 9)
        np.testing.assert_array_equal(plane, rgb[..., k] if k < 3 else alpha)
    back = imageio_.read_image(path)
    np.testing.assert_array_equal(back, np.concatenate([rgb, alpha[..., None]], -1))
    assert imageio_.image_size(path) == (9, 6)


def test_missing_and_corrupt_files_raise_input_error(tmp_path):
    with pytest.raises(InputError, match="not found"):
        imageio_.read_image(tmp_path / "none.png")
    with pytest.raises(InputError, match="not found"):
        imageio_.image_size(tmp_path / "none.png")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not a png at all")
    with pytest.raises(InputError, match="bad.png"):
        imageio_.read_image(bad)
    with pytest.raises(InputError, match="bad.png"):
        imageio_.image_size(bad)
    bad_exr = tmp_path / "bad.exr"
    bad_exr.write_bytes(b"nope")
    with pytest.raises(InputError, match="bad.exr"):
        imageio_.read_image(bad_exr)


def test_interrupted_write_leaves_nothing(tmp_path, monkeypatch):
    def explode(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(Image.Image, "save", explode)
    with pytest.raises(KeyboardInterrupt):
        imageio_.write_png(tmp_path / "x.png", np.zeros((2, 2, 3)))
    assert list(tmp_path.iterdir()) == []


def test_srgb_curve_round_trip():
    x = np.linspace(0, 1, 101, dtype=np.float32)
    np.testing.assert_allclose(imageio_.linear_to_srgb(imageio_.srgb_to_linear(x)), x, atol=1e-5)
    assert imageio_.srgb_to_linear(np.float32(0.5)) == pytest.approx(0.21404, abs=1e-4)
