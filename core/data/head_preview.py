"""Preview renders of a head model, drawn by the reference mesh renderer (:mod:`.mesh_render`): a few
poses and expressions seen from a few directions."""

from __future__ import annotations

import os

import numpy as np
import torch

from ..camera import Camera
from ..errors import ModelFileError
from ..flame.expression_roles import role_expression
from ..flame.model import FlameModel
from .mesh_render import render_mesh

VIEWS = (("front", 0.0, 0.0), ("three_quarter", 40.0, 8.0), ("profile", 90.0, 0.0))


def _expression(model: FlameModel, *roles: str, amount: float = 1.5) -> torch.Tensor:
    """An expression vector making each role (by component name, or by geometry on FLAME files)."""
    expr = sum(role_expression(model.arrays, role, amount) for role in roles)
    return torch.as_tensor(np.asarray(expr, np.float32))[None]


def preview_poses(model: FlameModel) -> dict[str, dict[str, torch.Tensor]]:
    """Named poses that show the model's range: neutral, an open mouth, expressions, a turn."""
    jaw_open = torch.tensor([[0.3, 0.0, 0.0]])
    return {
        "neutral": {},
        "jaw_open": {"jaw_pose": jaw_open},
        "smile": {"expr": _expression(model, "smile")},
        "blink_brows": {"expr": _expression(model, "blink", "brow_raise", amount=1.0)},
        "pucker_look": {"expr": _expression(model, "pucker"), "eyes_pose": torch.tensor([[0.0, 0.3, 0.0] * 2])},
        "turn_speak": {"rotation": torch.tensor([[0.1, 0.35, 0.0]]), "jaw_pose": 0.5 * jaw_open},
    }


def view_camera(vertices: np.ndarray, azimuth_deg: float, elevation_deg: float, size: int) -> Camera:
    """A camera 1 m from the head's centre that frames the whole head."""
    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    extent = float(np.max(vertices.max(0) - vertices.min(0)))
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    eye = centre + np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    fx = 0.8 * size / extent  # the head spans ~80% of the frame at 1 m
    return Camera.look_at(eye, centre, width=size, height=size, fx=fx)


def render_preview_sheet(path: str | os.PathLike, size: int = 256):
    """Render every preview pose from every view; returns the grid image and the named tiles."""
    model = FlameModel.load(path)
    arrays = model.arrays
    if arrays.vt is None or arrays.texture is None:
        raise ModelFileError(path, "vt/ft/texture", "previews need UVs and a texture in the model file")
    rest = model()[0].numpy()
    texture = arrays.texture.astype(np.float32) / 255.0
    tiles = {}
    rows = []
    with torch.no_grad():
        for pose_name, params in preview_poses(model).items():
            vertices = model(**params)[0].double().numpy()
            row = []
            for view_name, azimuth, elevation in VIEWS:
                camera = view_camera(rest, azimuth, elevation, size)
                rgb, _ = render_mesh(vertices, arrays.faces, arrays.vt, arrays.ft, texture, camera)
                tiles[f"{pose_name}_{view_name}"] = rgb
                row.append(rgb)
            rows.append(np.concatenate(row, axis=1))
    return np.concatenate(rows, axis=0), tiles
