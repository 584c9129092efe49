"""Per-camera extrinsic refinement: a learnable 6-DoF offset per training camera, shared by all
timesteps, for captures whose calibration is off (the camera-free setting).

Each camera ``i`` gets a rotation ``ω_i`` (axis-angle, world axes, about the camera's own centre)
and a shift ``τ_i`` of its centre (metres, world axes), both zero at the start. The refined
camera has camera-to-world rotation ``exp(ω)·R`` and centre ``c + τ``.

The splat engine takes its camera as fixed numbers, so the offset is applied to the scene instead:
rendering world points ``X`` with the refined camera is rendering ``exp(−ω)(X − c − τ) + c`` with
the calibrated one (means and rotations of the Gaussians move; sizes do not). Only the view
direction of the SH colours is off, by the rotation ``ω`` itself (a fraction of a degree).

Gauge: ``rigid`` (the default) removes after every optimiser step the part of the offsets that is
one rigid motion of the whole rig (a rotation about the world origin and a shift, fitted by least
squares, centre shifts weighed by the rig's radius). That motion is what the images pin only
weakly: with FLAME fine-tuning every timestep's pose can follow it, in Freeze the Gaussians can
slide within their triangles. Everything else stays free, a common turn of every camera about its
own centre included: that one moves the head in every view, so the images pin it. ``mean`` keeps the
mean rotation and the mean centre shift at zero separately: it also holds that common turn at the
calibration's mean error (about 1/√N of one camera's). ``none`` leaves the offsets free.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import torch
from torch import nn

from ..avatar.binding import matrix_to_quaternion, quaternion_multiply
from ..camera import Camera
from ..flame.lbs import axis_angle_to_matrix
from .config import CAMERA_GAUGES


class CameraOffsets(nn.Module):
    """Offsets of the cameras ``cameras`` (id → calibrated :class:`Camera`), one parameter each,
    so Adam steps only the cameras a step rendered (the others get no gradient)."""

    def __init__(self, cameras: dict[str, Camera], gauge: str = CAMERA_GAUGES[0]):
        super().__init__()
        if gauge not in CAMERA_GAUGES:
            raise ValueError(f"gauge must be one of {CAMERA_GAUGES}, got {gauge!r}")
        self.ids = sorted(cameras)
        self.index = {cid: i for i, cid in enumerate(self.ids)}
        self.calibrated = {cid: cameras[cid] for cid in self.ids}
        self.gauge = gauge
        self.rotation = nn.ParameterList([nn.Parameter(torch.zeros(3)) for _ in self.ids])
        self.translation = nn.ParameterList([nn.Parameter(torch.zeros(3)) for _ in self.ids])
        centres = np.stack([cameras[cid].center for cid in self.ids])
        self.register_buffer("centres", torch.as_tensor(centres, dtype=torch.float32))
        self._rigid_basis = _rigid_motions(centres)

    def __contains__(self, camera_id: str) -> bool:
        return camera_id in self.index

    def values(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(rotation (C,3), translation (C,3))`` of every camera, detached."""
        return (torch.stack([p.detach() for p in self.rotation]), torch.stack([p.detach() for p in self.translation]))

    def move_scene(self, world: dict[str, torch.Tensor], camera_id: str, centre=None) -> dict[str, torch.Tensor]:
        """World Gaussians as the calibrated camera must see them to show the refined camera's view.
        ``centre``: the frame's own camera centre, when it is not the first pose's (a union of
        sequences shifts each camera per sequence; the camera turns about where it is)."""
        if camera_id not in self.index:
            return world
        i = self.index[camera_id]
        undo = axis_angle_to_matrix(-self.rotation[i])
        centre = self.centres[i] if centre is None else torch.as_tensor(centre, dtype=torch.float32)
        means = (world["means"] - centre - self.translation[i]) @ undo.T + centre
        quats = quaternion_multiply(matrix_to_quaternion(undo)[None], world["quats"])
        return {**world, "means": means, "quats": quats}

    @torch.no_grad()
    def fix_gauge(self) -> None:
        """Remove the rig's rigid motion (``gauge = "rigid"``) or the mean rotation and the mean
        centre shift (``"mean"``) from the offsets."""
        if self.gauge == "none" or len(self.ids) < 2:
            return
        if self.gauge == "mean":
            for group in (self.rotation, self.translation):
                mean = torch.stack([p for p in group]).mean(0)
                for p in group:
                    p.sub_(mean)
            return
        rotation, translation = self.values()
        flat = torch.cat([rotation, translation], 1).double().flatten().numpy()
        basis, weights = self._rigid_basis
        coefficients = np.linalg.lstsq(basis * weights[:, None], flat * weights, rcond=None)[0]
        moved = torch.as_tensor(basis @ coefficients, dtype=torch.float32).reshape(len(self.ids), 6)
        for i in range(len(self.ids)):
            self.rotation[i].sub_(moved[i, :3])
            self.translation[i].sub_(moved[i, 3:])

    @torch.no_grad()
    def start_from(self, cameras: dict[str, Camera], source=None) -> None:
        """Set each offset so that its camera is ``cameras[id]`` (e.g. an earlier run's refined
        cameras: a new round with a fresh avatar); cameras the file lacks keep a zero offset."""
        from ..errors import InputError

        for camera_id, i in self.index.items():
            start = cameras.get(camera_id)
            if start is None:
                continue
            calibrated = self.calibrated[camera_id]
            if not np.allclose(start.K, calibrated.K, rtol=1e-4) or (start.width, start.height) != (
                    calibrated.width, calibrated.height):
                raise InputError(source, camera_id, "intrinsics or image size differ from the capture's camera "
                                                    "(cameras of another capture?)")
            turn = start.w2c[:3, :3].T @ calibrated.w2c[:3, :3]  # exp(ω) = R_start · R_calibrated⁻¹ (camera-to-world)
            self.rotation[i].copy_(_axis_angle(turn))
            self.translation[i].copy_(torch.as_tensor(start.center - calibrated.center))

    def param_groups(self, cameras) -> list[dict]:
        """The optimiser's groups ``cameras.rotation`` and ``cameras.translation`` (``cameras``: the
        ``[cameras]`` settings); one parameter per camera."""
        return [{"params": list(self.rotation), "lr": cameras.rotation_lr, "name": "cameras.rotation"},
                {"params": list(self.translation), "lr": cameras.translation_lr, "name": "cameras.translation"}]

    def refined_camera(self, camera_id: str) -> Camera:
        """The calibrated camera moved by its offset (float64 numbers, same intrinsics)."""
        camera = self.calibrated[camera_id]
        i = self.index[camera_id]
        rotation = axis_angle_to_matrix(self.rotation[i].detach().double()).numpy()
        c2w_rotation = rotation @ camera.w2c[:3, :3].T
        centre = camera.center + self.translation[i].detach().double().numpy()
        w2c = np.eye(4)
        w2c[:3, :3] = c2w_rotation.T
        w2c[:3, 3] = -c2w_rotation.T @ centre
        return dataclasses.replace(camera, w2c=w2c)

    def refined_cameras(self) -> dict[str, Camera]:
        return {cid: self.refined_camera(cid) for cid in self.ids}

    def state(self) -> dict:
        rotation, translation = self.values()
        return {"ids": list(self.ids), "gauge": self.gauge, "rotation": rotation.clone(),
                "translation": translation.clone()}

    @torch.no_grad()
    def load(self, state: dict, source=None) -> None:
        from ..errors import InputError

        if list(state.get("ids", [])) != self.ids:
            raise InputError(source, "cameras.ids", "the checkpoint's refined cameras differ from the capture's "
                                                    "training cameras")
        for group, values in ((self.rotation, state["rotation"]), (self.translation, state["translation"])):
            for p, value in zip(group, values):
                p.copy_(value)


def _rigid_motions(centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The offsets ``(ω_i, τ_i)`` of every camera, flattened ``(6C,)``, that a small rigid motion of
    the whole rig makes, as a basis ``(6C, 6)`` over (rotation ω₀ about the origin, shift t₀):
    ``ω_i = ω₀``, ``τ_i = ω₀ × c_i + t₀``; and the least-squares weights that make a centre shift
    of one rig radius count as one radian."""
    count = len(centres)
    basis = np.zeros((count, 6, 6))
    for i, c in enumerate(np.asarray(centres, np.float64)):
        basis[i, :3, :3] = np.eye(3)
        basis[i, 3:, :3] = -np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]])  # ω₀ × c = −[c]× ω₀
        basis[i, 3:, 3:] = np.eye(3)
    radius = max(float(np.sqrt(np.mean(np.sum((centres - centres.mean(0)) ** 2, 1)))), 1e-6)
    weights = np.tile(np.r_[np.ones(3), np.full(3, 1.0 / radius)], count)
    return basis.reshape(6 * count, 6), weights


def _axis_angle(matrix: np.ndarray) -> torch.Tensor:
    """A rotation matrix as its axis-angle vector (through the quaternion: exact for every angle)."""
    w, *xyz = matrix_to_quaternion(torch.as_tensor(matrix, dtype=torch.float64)).tolist()
    vector = torch.tensor(xyz, dtype=torch.float64)
    norm = float(vector.norm())
    return (vector * (2.0 * np.arctan2(norm, w) / norm) if norm > 1e-12 else 2.0 * vector).float()


def write_refined_cameras(path: str | os.PathLike, offsets: CameraOffsets) -> None:
    """``RUN/cameras_refined.json``: camera id → the capture's camera fields (as ``cameras_gt.json``)."""
    from ..data.camera_file import write_cameras

    write_cameras(path, offsets.refined_cameras())
