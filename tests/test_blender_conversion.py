"""The Blender-free scene conversions (core/for_blender/): axes, cameras, head rig, tracking.

No bpy here: Blender's projection of a camera is written out in numpy from its view-plane rules
(horizontal sensor fit, shifts in units of the width, pixel aspect), so the camera maths is
checked without Blender; tests/test_blender_addon.py checks the same against the real bpy.
"""

import math

import numpy as np
import pytest
from conftest import make_toy_model

from mogaface.core.camera import Camera
from mogaface.core.errors import InputError
from mogaface.core.flame.model_file import write_model_file
from mogaface.core.for_blender.axes import (
    FLAME_TO_BLENDER,
    blender_to_flame,
    flame_to_blender,
    frame_to_timestep,
    image_pixels,
    timestep_to_frame,
)
from mogaface.core.for_blender.cameras import BlenderCamera, blender_camera
from mogaface.core.for_blender.head_rig import (
    POSE_PROPERTIES,
    HeadRig,
    fit_components,
    load_head_model,
    read_identity,
    zero_pose,
)
from mogaface.core.for_blender.tracking import keyframe_columns, read_tracking, tracking_channels
from mogaface.core.io.npz import save_npz


def test_axis_conversion_is_the_documented_rotation():
    assert np.allclose(flame_to_blender([0, 1, 0]), [0, 0, 1])  # up stays up
    assert np.allclose(flame_to_blender([0, 0, 1]), [0, -1, 0])  # the face looks at Blender's −y
    assert np.allclose(flame_to_blender([1, 0, 0]), [1, 0, 0])
    assert math.isclose(np.linalg.det(FLAME_TO_BLENDER), 1.0)
    points = np.random.default_rng(0).normal(size=(10, 3))
    assert np.allclose(blender_to_flame(flame_to_blender(points)), points)


def blender_projection(settings: BlenderCamera, points_blender):
    """Pixels (OpenCV u right, v down) where Blender's camera model images Blender-world points."""
    width, height = settings.resolution
    ax, ay = settings.pixel_aspect
    ycor = ay / ax
    local = (np.linalg.inv(settings.matrix_world) @ np.c_[points_blender, np.ones(len(points_blender))].T).T
    depth = -local[:, 2]
    pixsize = settings.sensor_width / settings.lens / width  # view-plane units per pixel at depth 1
    x_plane, y_plane = local[:, 0] / depth, local[:, 1] / depth
    # The view plane spans [-W/2, W/2]·pixsize (x) and [-ycor·H/2, ycor·H/2]·pixsize (y), shifted.
    u = (x_plane / pixsize - settings.shift_x * width) + 0.5 * width
    v_up = (y_plane / pixsize - settings.shift_y * width) / ycor + 0.5 * height
    return np.stack([u, height - v_up], axis=1)


@pytest.mark.parametrize("fy_ratio", [1.0, 1.07, 0.9])
def test_camera_settings_reproduce_the_opencv_projection(fy_ratio):
    camera = Camera.look_at(
        [0.3, 0.2, 1.1], [0, 0.02, 0], width=64, height=48, fx=80.0, fy=80.0 * fy_ratio, cx=29.3, cy=27.1, camera_id="a"
    )
    settings = blender_camera(camera)
    assert settings.sensor_fit == "HORIZONTAL" and min(settings.pixel_aspect) == 1.0
    assert math.isclose(settings.lens, 80.0 * 36.0 / 64)
    points = np.random.default_rng(1).normal(scale=0.1, size=(50, 3))
    expected, _ = camera.project(points)
    got = blender_projection(settings, flame_to_blender(points))
    assert np.abs(got - expected).max() < 1e-9


def test_timesteps_map_to_frames_from_one():
    assert timestep_to_frame(0) == 1 and frame_to_timestep(timestep_to_frame(7)) == 7


def test_keyframe_columns_are_frame_value_pairs():
    columns = keyframe_columns([1, 2], [[0.5, -1.0], [0.25, 2.0]])
    assert [c.tolist() for c in columns] == [[1, 0.5, 2, 0.25], [1, -1.0, 2, 2.0]]


def test_fit_components_pads_and_cuts():
    assert fit_components([1, 2], 4).tolist() == [1, 2, 0, 0]
    assert fit_components([[1, 2, 3]], 2).tolist() == [[1, 2]]


def test_image_pixels_flip_rows_and_add_alpha():
    image = np.zeros((2, 3, 3), np.uint8)
    image[0] = 255  # top row white
    pixels = image_pixels(image).reshape(2, 3, 4)
    assert pixels[1, :, :3].min() == 1.0 and pixels[0, :, :3].max() == 0.0 and pixels[..., 3].min() == 1.0


@pytest.fixture
def toy_head_file(tmp_path):
    path = tmp_path / "toy.npz"
    write_model_file(path, make_toy_model())
    return path


def test_shape_key_blend_with_pose_key_equals_the_core_evaluation(toy_head_file):
    rng = np.random.default_rng(2)
    offset = rng.normal(scale=0.01, size=(40, 3))
    rig = HeadRig(load_head_model(toy_head_file), np.array([0.5, -1.0, 0.2, 0.0]), offset)
    expr = rng.normal(size=3)
    pose = {name: rng.normal(scale=0.3, size=size) for name, (_, size) in POSE_PROPERTIES.items()}
    keys = rig.expression_keys()
    basis = rig.basis()
    blended = basis + np.tensordot(expr, keys - basis, axes=1) + (rig.pose_key(expr, pose) - basis)
    assert np.abs(blended - flame_to_blender(rig.evaluate(expr, pose))).max() < 1e-12
    # At rest, the pose key is the basis.
    assert np.abs(rig.pose_key(np.zeros(3), zero_pose()) - basis).max() < 1e-12


def test_models_are_cached_per_file(toy_head_file):
    assert load_head_model(toy_head_file) is load_head_model(toy_head_file)


def write_tracking(folder, n, n_expr=3, names=None):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(3)
    rows = []
    for i in range(n):
        row = {"shape": np.zeros(4), "expr": rng.normal(size=(1, n_expr))}
        row.update({k: rng.normal(scale=0.1, size=(1, size)) for k, (_, size) in POSE_PROPERTIES.items()})
        save_npz(folder / (names[i] if names else f"{10 + 2 * i:05d}.npz"), row)
        rows.append(row)
    return rows


def test_tracking_channels_key_each_timestep_on_its_frame(tmp_path):
    rows = write_tracking(tmp_path / "fp", 3, n_expr=5)
    channels = tracking_channels(tmp_path / "fp", n_expr=3)
    assert channels.frames.tolist() == [11, 13, 15]
    assert "5 expression components" in channels.note
    assert len(channels.expressions) == 3
    assert np.allclose(channels.expressions[1].reshape(-1, 2)[:, 1], [r["expr"][0, 1] for r in rows])
    jaw = channels.pose["mogaface_jaw_pose"]
    assert len(jaw) == 3 and np.allclose(jaw[2].reshape(-1, 2)[:, 1], [r["jaw_pose"][0, 2] for r in rows])
    assert len(channels.pose["mogaface_eyes_pose"]) == 6


def test_tracking_errors_name_the_folder_or_file(tmp_path):
    with pytest.raises(InputError, match="no .npz files"):
        read_tracking(tmp_path)
    with pytest.raises(InputError, match="not a folder"):
        read_tracking(tmp_path / "missing")
    save_npz(tmp_path / "00000.npz", {"expr": np.zeros((1, 3))})
    with pytest.raises(InputError, match="00000.npz"):
        read_tracking(tmp_path)


def test_identity_comes_from_any_npz_with_a_shape(tmp_path):
    save_npz(tmp_path / "only.npz", {"shape": np.arange(6.0)[None]})
    shape, offset = read_identity(tmp_path / "only.npz", n_shape=4, n_vertices=40)
    assert shape.tolist() == [0, 1, 2, 3] and offset is None
    save_npz(tmp_path / "offset.npz", {"shape": np.ones(2), "static_offset": np.ones((1, 40, 3))})
    shape, offset = read_identity(tmp_path / "offset.npz", n_shape=4, n_vertices=40)
    assert shape.tolist() == [1, 1, 0, 0] and offset.shape == (40, 3)
    with pytest.raises(InputError, match="offset.npz.*static_offset"):
        read_identity(tmp_path / "offset.npz", n_shape=4, n_vertices=41)
    save_npz(tmp_path / "none.npz", {"expr": np.ones(2)})
    with pytest.raises(InputError, match="none.npz.*shape"):
        read_identity(tmp_path / "none.npz", n_shape=4, n_vertices=40)
