"""The one colour conversion for Blender, the viewport's framing, and the ready extension zip."""

import pathlib
import subprocess
import zipfile

import numpy as np
import pytest

from mogaface.core.camera import Camera
from mogaface.core.errors import InputError
from mogaface.core.for_blender.render import RenderRequest, RenderResult, blender_rgba, srgb_from_blender, view_framing

ROOT = pathlib.Path(__file__).resolve().parents[1]


def result(rgb, alpha, background=None) -> RenderResult:
    camera = Camera(K=np.eye(3), w2c=np.eye(4), width=rgb.shape[1], height=rgb.shape[0])
    request = RenderRequest("avatar.pt", {}, camera, background)
    alpha = np.asarray(alpha, np.float32)
    return RenderResult(request, np.asarray(rgb, np.float32), alpha, np.zeros_like(alpha))


def srgb_decode(v):  # IEC 61966-2-1, written out here
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def test_an_opaque_render_becomes_its_scene_linear_values_with_alpha_one():
    rgb = np.array([[[0.0, 0.5, 1.0], [0.04, 0.2, 0.735]]], np.float32)
    out = blender_rgba(result(rgb, [[0.3, 1.0]], background=(1.0, 1.0, 1.0)))
    assert out.shape == (1, 2, 4) and out.dtype == np.float32
    np.testing.assert_allclose(out[..., :3], srgb_decode(rgb), atol=1e-6)
    assert (out[..., 3] == 1).all()  # composited over the background: opaque
    assert abs(out[0, 0, 1] - 0.2140) < 1e-3  # sRGB 0.5 is 21.4 % linear light, not 50 %


def test_semi_transparent_pixels_keep_their_colour():
    """Premultiplied sRGB in, premultiplied linear out: the straight colour is decoded, not the product."""
    straight = np.array([0.8, 0.4, 0.1], np.float32)
    alphas = np.array([[1.0, 0.5, 0.1, 0.0]], np.float32)
    rgb = straight * alphas[..., None]  # what a transparent render holds
    out = blender_rgba(result(rgb, alphas))
    np.testing.assert_allclose(out[..., 3], alphas)
    for i, a in enumerate(alphas[0]):
        np.testing.assert_allclose(out[0, i, :3], srgb_decode(straight) * a, atol=1e-6)
    # decoding the premultiplied value itself would darken the half-covered pixel by a third
    assert out[0, 1, 0] / srgb_decode(rgb[0, 1, 0]) > 1.4
    # and back: what "Standard" shows over black is the core's premultiplied sRGB
    np.testing.assert_allclose(srgb_from_blender(out), rgb, atol=1e-5)


def test_the_round_trip_covers_every_8_bit_value():
    values = np.arange(256, dtype=np.float32) / 255
    rgb = np.repeat(values[None, :, None], 3, axis=2)
    out = blender_rgba(result(rgb, np.ones((1, 256), np.float32)))
    assert np.abs(np.round(srgb_from_blender(out) * 255) - np.arange(256)[None, :, None]).max() == 0


def test_where_one_camera_or_parallel_ones_look_is_the_axis_point_nearest_the_head():
    """A tracked clip's one camera (and parallel axes) meet nowhere: Import Capture frames the point
    of the axis nearest the origin, where a FLAME head stands (``look_point``'s least norm)."""
    from mogaface.core.camera import Camera, look_point

    one = Camera.look_at((0.3, 0.1, 0.6), (0.0, 0.05, 0.0), width=64, height=64, fx=60.0)
    axis, centre = one.w2c[2, :3], one.center
    assert np.allclose(look_point([one]), centre - (centre @ axis) * axis)
    parallel = [Camera.look_at((x, 0.0, 0.6), (x, 0.0, 0.0), width=64, height=64, fx=60.0) for x in (0.0, 1.0, 2.0)]
    assert np.allclose(look_point(parallel), [1.0, 0.0, 0.0])


def test_an_import_frames_the_head_of_a_synthetic_capture(procedural_head):
    """The synthetic rig's cameras look at the head: the point an import frames is its centre."""
    from mogaface.core.camera import look_point
    from mogaface.core.data.generator import camera_dome

    vertices = procedural_head["v_template"]
    cameras, _ = camera_dome(16, 64, vertices, np.random.default_rng(0))
    head = 0.5 * (vertices.min(0) + vertices.max(0))
    assert np.linalg.norm(look_point(cameras) - head) < 0.01  # within 1 cm of the head's centre


def test_view_framing_sees_every_point():
    points = np.array([[0.0, 0.0, 0.0], [1.0, -1.0, 0.2], [-1.0, -0.8, 0.1], [0.0, 1.2, 0.3]])
    centre, distance = view_framing(points, 50.0, 1200, 800)
    # every point inside the view cone of the narrower side, looking from any direction at the centre
    half_fov = np.arctan(36.0 / 50.0 * 800 / 1200)
    for direction in np.eye(3):
        eye = centre + direction * distance
        to_points = points - eye
        angles = np.arccos(np.clip((to_points @ -direction) / np.linalg.norm(to_points, axis=1), -1, 1))
        assert angles.max() < half_fov
    assert distance < 3 * np.linalg.norm(points - centre, axis=1).max() / np.sin(half_fov)  # not a speck
    with pytest.raises(InputError):
        view_framing(np.zeros((0, 3)), 50.0, 10, 10)


def test_build_extension_writes_a_valid_zip_without_tests_or_venv(tmp_path):
    out = tmp_path / "dist"
    run = subprocess.run(["bash", str(ROOT / "scripts" / "build_extension.sh"), "--output-dir", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    version = next(line.split('"')[1] for line in (ROOT / "blender_manifest.toml").read_text().splitlines()
                   if line.startswith("version"))
    archive = out / f"mogaface-{version}.zip"
    assert archive.is_file() and str(archive) in run.stdout
    with zipfile.ZipFile(archive) as zipped:
        names = zipped.namelist()
        assert zipped.testzip() is None
        manifest = zipped.read("blender_manifest.toml").decode()
    assert 'id = "mogaface"' in manifest and f'version = "{version}"' in manifest
    assert "__init__.py" in names and "operators/handlers/viewport.py" in names and "core/for_blender/render.py" in names
    assert not [n for n in names if n.startswith(("tests/", ".venv/", "docs/", "bench/", ".git/", "dist/"))
                or "__pycache__" in n or n.endswith(".sh")]
    # tracked files only: a file left in the working tree is not shipped
    tracked = set(subprocess.run(["git", "-C", str(ROOT), "ls-files"], capture_output=True, text=True,
                                 check=True).stdout.split())
    assert set(n for n in names if not n.endswith("/")) <= tracked
