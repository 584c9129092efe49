"""An avatar as Gaussian PLY files, and back.

- **World space**: the Gaussians of one timestep, posed, in the 3DGS layout any splat viewer
  reads (log-scales, logit opacity, wxyz rotations, zero normals). What a viewer shows is what
  :meth:`Avatar.render` shows for that timestep.
- **Binding space**: the trained, triangle-local parameters plus ``binding_0`` (GaussianAvatars'
  layout) and, beside the file, ``FILE.flame_param.npz`` with the FLAME parameters that pose it
  (GaussianAvatars' layout: a leading time axis of one on every parameter but ``shape``).
  GaussianAvatars poses them as we do (``binding.bound_to_world``): world rotation
  ``face_orien_quat ⊗ rotation`` (its ``get_rotation``), position ``face_scaling · R·xyz + centre``,
  scale ``face_scaling · exp(scaling)``. An avatar with MoGaFace texture offsets gets the offsets of
  the exported timestep baked in (they follow the expression; a PLY holds one set), so that
  timestep poses exactly; other timesteps pose the same Gaussians without their own offsets.
  :func:`import_binding_ply` turns such a file and its head model back into an Avatar (a head
  model with FLAME's 5023 vertices gains its teeth when the face ids reach them).
  Also ``flame_param.npz`` (that exact name, in the PLY's folder): the motion in the form
  GaussianAvatars' viewer opens beside a PLY, one row per timestep (:func:`gaussian_avatars_motion`).

SH bands above the active degree are written as zeros (they take no part in a render), so a
file always has degree-``max_sh_degree`` columns, as the 3DGS loader expects, and an imported
avatar uses every band it holds.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np
import torch

from ..data import layout
from ..errors import InputError
from ..flame.model import FlameModel
from ..io.npz import save_npz
from ..io.ply import read_gaussian_ply, write_gaussian_ply
from .avatar import Avatar, flame_params_to_torch
from .gaussians import BoundGaussians, rgb_to_sh_dc

FLAME_PARAM_SUFFIX = ".flame_param.npz"
GA_MOTION_FILE = "flame_param.npz"  # GaussianAvatars' viewer opens exactly this name beside the PLY
GA_SHAPE_COUNT, GA_EXPR_COUNT = 300, 100  # GaussianAvatars' FLAME defaults
_OPACITY_EPS = 1e-7  # keeps the logit of a saturated opacity finite


def rendered_sh(gaussians: BoundGaussians) -> torch.Tensor:
    """All ``(max+1)²`` SH coefficients, with the bands above the active degree zeroed."""
    used = (gaussians.active_sh_degree + 1) ** 2 - 1
    rest = gaussians.sh_rest.detach().clone()
    rest[:, used:] = 0.0
    return torch.cat([gaussians.sh_dc.detach(), rest], dim=1)


def flame_param_path(ply_path: str | os.PathLike) -> pathlib.Path:
    """``FILE.flame_param.npz`` beside ``FILE.ply``."""
    ply_path = pathlib.Path(ply_path)
    return ply_path.with_name(ply_path.stem + FLAME_PARAM_SUFFIX)


def world_ply_arrays(avatar: Avatar, flame_params: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """The posed Gaussians of one timestep as PLY columns (``write_gaussian_ply``'s arguments).

    Taken from :meth:`Avatar.world_gaussians`, exactly what a render rasterizes.
    """
    with torch.no_grad():
        world = avatar.world_gaussians(flame_params_to_torch(flame_params))
        colors = world["colors"]
        if colors.dim() == 2:  # plain RGB: the DC term that gives it
            colors = rgb_to_sh_dc(colors)[:, None]
        coefficients = (avatar.gaussians.max_sh_degree + 1) ** 2
        sh = torch.zeros(len(colors), max(coefficients, colors.shape[1]), 3)
        sh[:, : colors.shape[1]] = colors
        opacities = world["opacities"].clamp(_OPACITY_EPS, 1.0 - _OPACITY_EPS)
        return {
            "means": world["means"],
            "scales_log": torch.log(world["scales"]),
            "quats": world["quats"] / world["quats"].norm(dim=-1, keepdim=True),
            "opacity_logit": torch.log(opacities) - torch.log1p(-opacities),
            "sh": sh,
        }


def export_world_ply(avatar: Avatar, flame_params: dict[str, np.ndarray], path: str | os.PathLike) -> pathlib.Path:
    """Write one timestep's posed Gaussians as a 3DGS PLY (atomically)."""
    write_gaussian_ply(path, **world_ply_arrays(avatar, flame_params))
    return pathlib.Path(path)


def gaussian_avatars_motion(frames: dict[int, dict[str, np.ndarray]], n_vertices: int) -> dict[str, np.ndarray]:
    """Per-timestep FLAME parameters as GaussianAvatars keeps them (and saves as ``flame_param.npz``).

    ``frames``: timestep → parameters. Row ``t`` is timestep ``t`` (GaussianAvatars selects a
    mesh by ``flame_param[key][timestep]`` over ``max(timestep) + 1`` rows, train and test
    together); a timestep missing from ``frames`` keeps a zero row, as GaussianAvatars leaves it.
    ``shape (300,)``, ``expr (T,100)``, ``rotation``/``neck_pose``/``jaw_pose``/``translation (T,3)``,
    ``eyes_pose (T,6)``, ``static_offset (1,V,3)``, ``dynamic_offset (T,V,3)``, float32, with
    ``V`` its FLAME with teeth (5143): fewer components are padded with zeros, and offsets of a
    5023-vertex FLAME get zero rows for the teeth (GaussianAvatars pads them the same way).
    """
    from ..flame.teeth import FLAME_VERTEX_COUNT, TEETH_VERTEX_COUNT

    if not frames:
        raise InputError(None, "frames", "no timesteps to write")
    if min(frames) < 0:
        raise InputError(None, "timestep", f"timesteps must be non-negative, got {min(frames)}")
    rows = n_vertices + TEETH_VERTEX_COUNT if n_vertices == FLAME_VERTEX_COUNT else n_vertices
    count = max(frames) + 1
    first = frames[min(frames)]

    def padded(value, count):
        value = np.asarray(value, np.float32)
        return np.pad(value, [(0, 0)] * (value.ndim - 1) + [(0, max(0, count - value.shape[-1]))])

    def offset(params, name):
        value = np.asarray(params.get(name, np.zeros((n_vertices, 3))), np.float32).reshape(-1, 3)
        return np.pad(value, [(0, rows - len(value)), (0, 0)])

    sizes = {"expr": GA_EXPR_COUNT, "rotation": 3, "neck_pose": 3, "jaw_pose": 3, "eyes_pose": 6, "translation": 3}
    out = {key: np.zeros((count, size), np.float32) for key, size in sizes.items()}
    out["dynamic_offset"] = np.zeros((count, rows, 3), np.float32)
    for t, params in frames.items():
        out["expr"][t] = padded(params["expr"], GA_EXPR_COUNT)
        for key in ("rotation", "neck_pose", "jaw_pose", "eyes_pose", "translation"):
            out[key][t] = np.asarray(params[key], np.float32)
        out["dynamic_offset"][t] = offset(params, "dynamic_offset")
    out["shape"] = padded(first["shape"], GA_SHAPE_COUNT)
    out["static_offset"] = offset(first, "static_offset")[None]
    return out


def bound_parameters(avatar: Avatar, flame_params: dict[str, np.ndarray] | None, source=None) -> dict[str, torch.Tensor]:
    """The triangle-local Gaussians a binding-space PLY holds: the avatar's own, plus the texture
    offsets of ``flame_params`` for an avatar with MoGaFace texture attention (added as its render
    adds them, before the binding poses them)."""
    g = avatar.gaussians
    local = {"means": g.local_position, "scales_log": g.local_log_scale, "quats": g.local_rotation,
             "opacity_logit": g.opacity_logit}
    model = getattr(avatar, "model", None)
    if model is not None and model.texture is not None:
        if flame_params is None:
            raise InputError(source, "timestep", "an avatar with MoGaFace texture offsets needs the timestep whose "
                                                 "offsets the binding-space file holds")
        with torch.no_grad():
            offsets = model.texture_offsets(g, avatar.flame.faces, flame_params_to_torch(flame_params))
        local = {"means": local["means"] + offsets["position"], "scales_log": local["scales_log"] + offsets["log_scale"],
                 "quats": local["quats"] + offsets["rotation"],
                 "opacity_logit": local["opacity_logit"] + offsets["opacity"][:, 0]}
    return {k: v.detach() for k, v in local.items()}


def export_binding_ply(
    avatar: Avatar, path: str | os.PathLike, flame_params: dict[str, np.ndarray] | None = None,
    motion: dict[int, dict[str, np.ndarray]] | None = None, timestep: int = 0,
) -> list[pathlib.Path]:
    """Write the triangle-bound Gaussians (GaussianAvatars' layout; texture offsets of
    ``flame_params`` baked in, see :func:`bound_parameters`) and, given parameters, the
    ``FILE.flame_param.npz`` beside it; given ``motion`` (timestep → parameters, or else
    ``flame_params`` as ``timestep``), GaussianAvatars' ``flame_param.npz`` too. Returns the files written."""
    g = avatar.gaussians
    write_gaussian_ply(path, **bound_parameters(avatar, flame_params, path), sh=rendered_sh(g), binding=g.binding)
    written = [pathlib.Path(path)]
    if flame_params is not None:
        params = layout.normalize_flame_params(flame_params, path)
        npz = flame_param_path(path)
        save_npz(npz, layout.batched_flame_params(params))
        written.append(npz)
        motion = {timestep: params} if motion is None else motion
    if motion:
        ga = pathlib.Path(path).with_name(GA_MOTION_FILE)
        save_npz(ga, gaussian_avatars_motion(motion, avatar.flame.n_vertices))
        written.append(ga)
    return written


def bound_head(head_file: str | os.PathLike, max_face: int, source=None) -> FlameModel:
    """The head model whose faces ``binding_0`` ids up to ``max_face`` refer to: the model as it is,
    or, for FLAME's 5023 vertices and ids beyond its faces, FLAME with the teeth VHAP and
    GaussianAvatars add (:mod:`..flame.teeth`, 10144 faces)."""
    from ..flame.teeth import FLAME_VERTEX_COUNT, TEETH_VERTEX_COUNT

    flame = FlameModel.load(head_file)
    if max_face >= len(flame.faces) and flame.n_vertices == FLAME_VERTEX_COUNT:
        flame = FlameModel.load(head_file, n_vertices=FLAME_VERTEX_COUNT + TEETH_VERTEX_COUNT)
    if max_face >= len(flame.faces):
        problem = f"face ids reach {max_face}, the head model has {len(flame.faces)} faces"
        if flame.n_vertices == FLAME_VERTEX_COUNT + TEETH_VERTEX_COUNT:
            problem += " (with FLAME's teeth)"
        raise InputError(source, "binding_0", problem)
    return flame


def import_binding_ply(path: str | os.PathLike, head_file: str | os.PathLike) -> Avatar:
    """An Avatar from a binding-space PLY and the head model its ``binding_0`` ids refer to."""
    data = read_gaussian_ply(path)
    if data["binding"] is None:
        raise InputError(path, "binding_0", "missing: a world-space PLY cannot be bound to a head model")
    flame = bound_head(head_file, int(data["binding"].max()) if len(data["binding"]) else -1, path)
    if data["sh_degree"] > 3:
        raise InputError(path, "f_rest", f"SH degree {data['sh_degree']} is above 3")
    sh = torch.from_numpy(data["sh"])
    gaussians = BoundGaussians(
        torch.from_numpy(data["binding"]),
        data["sh_degree"],
        local_position=torch.from_numpy(data["means"]),
        local_log_scale=torch.from_numpy(data["scales_log"]),
        local_rotation=torch.from_numpy(data["quats"]),
        opacity_logit=torch.from_numpy(data["opacity_logit"]),
        sh_dc=sh[:, :1],
        sh_rest=sh[:, 1:],
    )
    gaussians.active_sh_degree = data["sh_degree"]
    return Avatar(flame, gaussians, head_file, path, "binding_0")


def load_flame_param_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The FLAME parameters written beside a binding-space PLY (one timestep)."""
    from ..io.npz import load_npz

    arrays = load_npz(path)
    if "expr" in arrays and np.ndim(arrays["expr"]) == 2 and len(arrays["expr"]) != 1:
        raise InputError(path, "expr", f"holds {len(arrays['expr'])} timesteps; expected one")
    return layout.normalize_flame_params(arrays, path)


def world_ply_gaussians(path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """A world-space PLY as the splat engine's inputs (activated: scales, opacities)."""
    data = read_gaussian_ply(path)
    return {
        "means": torch.from_numpy(data["means"]),
        "quats": torch.from_numpy(data["quats"]),
        "scales": torch.exp(torch.from_numpy(data["scales_log"])),
        "opacities": torch.sigmoid(torch.from_numpy(data["opacity_logit"])),
        "colors": torch.from_numpy(data["sh"]),
    }


def render_world_ply(path: str | os.PathLike, camera, background=(1.0, 1.0, 1.0)):
    """Render a world-space PLY as it stands (no head model): what a 3DGS viewer would show."""
    from ..splat import rasterize
    from .avatar import camera_tensors

    g = world_ply_gaussians(path)
    viewmat, K = camera_tensors(camera)
    with torch.no_grad():
        return rasterize(
            g["means"], g["quats"], g["scales"], g["opacities"], g["colors"], viewmat, K,
            camera.width, camera.height, background=torch.as_tensor(background, dtype=torch.float32),
        )
