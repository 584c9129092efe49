"""An avatar: a head model, Gaussians bound to its triangles, and the one render call.

Training, evaluation, the command line and Blender all render through
:meth:`Avatar.render`, so what is trained is what is shown; :func:`render_arrays` is the one
way from an avatar (or a modulated one) and FLAME parameters to numpy images.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np
import torch

from ..camera import Camera
from ..errors import InputError
from ..flame.model import FlameModel
from ..io.atomic import atomic_path
from ..io.files import check_plain_name
from ..io.torch_file import check_format, load_torch_state, save_torch_state
from ..splat import SplatOutput, rasterize
from .camera_colour import recolour
from .gaussians import PARAMETER_NAMES, BoundGaussians

AVATAR_FORMAT = "mogaface-avatar"
AVATAR_VERSION = 1


def camera_tensors(camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """The splat engine's ``viewmat`` and ``K`` for a camera."""
    return torch.as_tensor(camera.w2c, dtype=torch.float32), torch.as_tensor(camera.K, dtype=torch.float32)


class Avatar(torch.nn.Module):
    """A FLAME-format head model with bound Gaussians.

    ``head_file`` is the model file the avatar was trained on (kept beside a saved avatar so
    the avatar is self-contained). ``source`` and ``field``: the file the Gaussians were read from and
    its name for their triangle ids (``avatar.pt``'s ``gaussians.binding``, a PLY's ``binding_0``),
    named by errors; the head model file when the Gaussians were made here. ``camera_colours``: the
    colours its run learned for its training cameras (camera id → change, :mod:`.camera_colour`),
    set by the run's loader; None otherwise.
    """

    def __init__(self, flame: FlameModel, gaussians: BoundGaussians, head_file: str | os.PathLike,
                 source: str | os.PathLike | None = None, field: str = "binding"):
        super().__init__()
        binding = gaussians.binding
        source = head_file if source is None else source
        if len(binding) == 0:
            raise InputError(source, field, "no Gaussians: expected at least one")
        if int(binding.min()) < 0 or int(binding.max()) >= len(flame.faces):
            raise InputError(source, field, f"Gaussians are bound to triangles the head model does not have: ids "
                                            f"{int(binding.min())}..{int(binding.max())}, expected ids in [0, "
                                            f"{len(flame.faces)}) ({pathlib.Path(head_file).name} has "
                                            f"{len(flame.faces)} faces)")
        self.flame = flame
        self.gaussians = gaussians
        self.head_file = pathlib.Path(head_file)
        self.camera_colours: dict | None = None

    @classmethod
    def initial(cls, head_file: str | os.PathLike, max_sh_degree: int = 3, n_vertices: int | None = None) -> "Avatar":
        """A new avatar: one faint grey Gaussian per triangle of the head model.

        ``n_vertices``: the tracking's vertex count (5143 adds FLAME's teeth, :mod:`..flame.teeth`).
        """
        flame = FlameModel.load(head_file, n_vertices=n_vertices)
        return cls(flame, BoundGaussians.one_per_triangle(len(flame.faces), max_sh_degree), head_file)

    def posed_vertices(self, flame_params: dict[str, torch.Tensor]) -> torch.Tensor:
        """Mesh vertices ``(V,3)`` for one timestep's FLAME parameters (each ``(1,n)``)."""
        return self.flame(**flame_params)[0]

    def world_gaussians(self, flame_params: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return self.world_posed(self.posed_vertices(flame_params), flame_params)

    def world_posed(self, vertices: torch.Tensor, flame_params: dict | None = None) -> dict[str, torch.Tensor]:
        """World Gaussians on the already posed mesh ``vertices (V,3)``; ``flame_params`` are read
        only by an avatar whose appearance follows them (:class:`~..correction.avatar.ModulatedAvatar`)."""
        return self.gaussians.world(vertices, self.flame.faces)

    def render(
        self, flame_params: dict[str, torch.Tensor], camera: Camera, background=(1.0, 1.0, 1.0), vertex_shift=None
    ) -> SplatOutput:
        """Render the avatar posed by ``flame_params`` as ``camera`` sees it (``vertex_shift``: a
        move of the posed mesh, a camera's delay along the motion, or None)."""
        vertices = self.posed_vertices(flame_params)
        return self.render_posed(vertices if vertex_shift is None else vertices + vertex_shift, camera, background)

    def render_posed(self, vertices: torch.Tensor, camera: Camera, background=(1.0, 1.0, 1.0)) -> SplatOutput:
        """Render the Gaussians bound to an already posed mesh ``vertices (V,3)``."""
        viewmat, K = camera_tensors(camera)
        world = self.world_posed(vertices)
        return rasterize(
            world["means"], world["quats"], world["scales"], world["opacities"], world["colors"],
            viewmat, K, camera.width, camera.height, background=torch.as_tensor(background, dtype=torch.float32),
        )

    # -- files -------------------------------------------------------------------------------
    def state(self) -> dict:
        """Everything a saved avatar holds, as tensors and plain values (``weights_only`` safe)."""
        return {
            "format": AVATAR_FORMAT,
            "version": AVATAR_VERSION,
            "head_file": self.head_file.name,
            "n_vertices": self.flame.n_vertices,
            "max_sh_degree": self.gaussians.max_sh_degree,
            "active_sh_degree": self.gaussians.active_sh_degree,
            "gaussians": {k: v.detach().clone() for k, v in self.gaussians.tensors().items()},
        }

    def save(self, path: str | os.PathLike) -> None:
        """Write the avatar atomically; the head model file must sit beside it (same folder)."""
        path = pathlib.Path(path)
        with atomic_path(path) as tmp:
            save_torch_state(self.state(), tmp)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Avatar":
        """Read an avatar saved by :meth:`save` (``weights_only``: nothing in it is executed)."""
        path = pathlib.Path(path)
        return cls.from_state(load_torch_state(path, "avatar file"), path.parent, source=path)

    @classmethod
    def from_state(cls, state: dict, folder: pathlib.Path, source=None) -> "Avatar":
        check_format(state, source, AVATAR_FORMAT, AVATAR_VERSION)
        tensors = state.get("gaussians")
        if not isinstance(tensors, dict):
            raise InputError(source, "gaussians", f"expected a table of tensors, got {type(tensors).__name__}")
        missing = [k for k in ("binding", *PARAMETER_NAMES) if k not in tensors]
        if missing:
            raise InputError(source, f"gaussians.{missing[0]}", "missing")
        for name in ("binding", *PARAMETER_NAMES):
            value = tensors[name]
            floating = name != "binding"
            if not isinstance(value, torch.Tensor) or value.is_floating_point() != floating or value.is_complex():
                kind = "a floating-point" if floating else "an integer"
                raise InputError(source, f"gaussians.{name}", f"expected {kind} tensor, got "
                                                              f"{getattr(value, 'dtype', type(value).__name__)}")
        if tensors["binding"].dim() != 1:
            raise InputError(source, "gaussians.binding", f"expected one triangle id a Gaussian (shape (N,)), got "
                                                          f"shape {tuple(tensors['binding'].shape)}")
        head_file = folder / check_plain_name(state.get("head_file"), source, "head_file")
        max_degree = _small_int(state, "max_sh_degree", 0, 3, source)
        active_degree = _small_int(state, "active_sh_degree", 0, max_degree, source)
        try:
            gaussians = BoundGaussians(tensors["binding"], max_degree, **{k: tensors[k] for k in PARAMETER_NAMES})
        except InputError as error:  # the same problem, named in this file
            raise InputError(source, f"gaussians.{error.field}", error.problem) from None
        gaussians.active_sh_degree = active_degree
        for name in PARAMETER_NAMES:
            if not bool(torch.isfinite(tensors[name]).all()):
                raise InputError(source, f"gaussians.{name}", "holds NaN or infinite values")
        n_vertices = state.get("n_vertices")
        if n_vertices is not None:
            n_vertices = _small_int(state, "n_vertices", 1, 10 ** 7, source)
        return cls(FlameModel.load(head_file, n_vertices=None if n_vertices is None else int(n_vertices)),
                   gaussians, head_file, source, "gaussians.binding")


def _small_int(state: dict, key: str, low: int, high: int, source) -> int:
    value = state.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise InputError(source, key, f"expected an integer in [{low}, {high}], got {value!r}")
    return value


def flame_params_to_torch(params: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """One timestep's numpy FLAME parameters (``(n,)`` each, ``static_offset (V,3)``) → ``(1,…)`` tensors."""
    return {k: torch.as_tensor(np.asarray(v, dtype=np.float32))[None] for k, v in params.items()}


def render_arrays(avatar, params: dict[str, np.ndarray], camera: Camera, background,
                  vertex_shift=None, colour=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rgb (H,W,3), alpha (H,W), depth (H,W))`` float32 of ``avatar`` posed by ``params``, without
    gradients: rgb as rendered (SH can overshoot [0, 1]), alpha clamped to [0, 1], depth the
    alpha-weighted one. ``vertex_shift``: a move of the posed mesh (a camera's delay), or None.
    ``colour``: a camera's colour (change ``[M − I | b]``, :mod:`.camera_colour`) its foreground is
    seen in, or None."""
    with torch.no_grad():
        out = avatar.render(flame_params_to_torch(params), camera, background, vertex_shift=vertex_shift)
        rgb = out.rgb if colour is None else recolour(out.rgb, out.alpha, background, colour)
    return (rgb.numpy().astype(np.float32), out.alpha.clamp(0.0, 1.0).numpy().astype(np.float32),
            out.depth.numpy().astype(np.float32))


def render_frame(avatar, params: dict[str, np.ndarray], camera: Camera, background, clamp: bool = True,
                 vertex_shift=None, colour=None) -> tuple[np.ndarray, np.ndarray]:
    """``(rgb (H,W,3), alpha (H,W))`` of :func:`render_arrays`; ``clamp=False`` keeps colours outside
    [0, 1] for compositing later."""
    rgb, alpha, _ = render_arrays(avatar, params, camera, background, vertex_shift, colour)
    return (np.clip(rgb, 0.0, 1.0) if clamp else rgb), alpha
