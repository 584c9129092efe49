"""The MoGaFace modules of one avatar in one place: encoder, fusion, correction head, bank, texture.

``spec`` (plain values) says which modules exist and their sizes, so a saved model rebuilds
without the training settings. Modes: ``off`` (Freeze: no correction), ``single`` (one view
per correction), ``multi`` (all given views, fused by cross-attention).
"""

from __future__ import annotations

import os
import pathlib

import torch
from torch import nn

from ..avatar.binding import triangle_frames
from ..errors import InputError
from ..io.atomic import atomic_path
from ..io.torch_file import check_format, load_torch_state, save_torch_state
from .bank import ExpressionBank
from .correction import CorrectionHead
from .encoder import ViewEncoder
from .fusion import MultiViewFusion
from .posing import canonical_points
from .texture_attention import LatentTextureAttention, code_size, flame_code

MODEL_FORMAT = "mogaface-modules"
# 2: the texture attention reads the FLAME code (1 read a per-timestamp image feature).
MODEL_VERSION = 2
MODES = ("off", "single", "multi")
SPEC_KEYS = ("mode", "bank", "texture", "input_size", "feature_dim", "encoder_width", "heads", "hidden",
             "plane_size", "plane_dim", "texture_hidden", "n_expr")


class MoGaFace(nn.Module):
    """The trainable MoGaFace modules plus their per-timestamp memory.

    ``timesteps`` and ``cameras`` (the training ones) fix the bank's rows and view slots;
    ``canonical_vertices`` is the neutral mesh whose bounding box scales the triplane's domain.
    """

    def __init__(self, spec: dict, timesteps: list[int], cameras: list[str], canonical_vertices: torch.Tensor):
        super().__init__()
        missing = [k for k in SPEC_KEYS if k not in spec]
        if missing:
            raise InputError(None, f"mogaface.{missing[0]}", "missing")
        if spec["mode"] not in MODES:
            raise InputError(None, "mogaface.mode", f"expected one of {', '.join(MODES)}, got {spec['mode']!r}")
        if spec["mode"] == "off" and (spec["bank"] or spec["texture"]):
            raise InputError(None, "mogaface.mode", "the bank and the texture attention need a correction mode "
                                                    "(single or multi), not 'off'")
        self.spec = {k: spec[k] for k in SPEC_KEYS}
        self.timesteps = list(timesteps)
        self.row = {t: i for i, t in enumerate(self.timesteps)}
        self.cameras = list(cameras)
        self.slot = {c: i for i, c in enumerate(self.cameras)}
        d = spec["feature_dim"]
        self.encoder = ViewEncoder(spec["input_size"], d, spec["encoder_width"])
        self.fusion = MultiViewFusion(d, spec["heads"])
        self.head = CorrectionHead(d, spec["n_expr"], spec["hidden"])
        self.bank = ExpressionBank(len(self.timesteps), len(self.cameras), spec["n_expr"]) if spec["bank"] else None
        self.texture = LatentTextureAttention(code_size(spec["n_expr"]), spec["plane_size"], spec["plane_dim"],
                                              spec["texture_hidden"]) if spec["texture"] else None
        vertices = canonical_vertices.detach().float()
        low, high = vertices.min(0).values, vertices.max(0).values
        self.register_buffer("canonical_vertices", vertices.clone())
        self.register_buffer("canonical_centre", 0.5 * (low + high))
        self.register_buffer("canonical_half_extent", (0.55 * (high - low).max()).reshape(1))
        self.register_buffer("correction_mean", torch.zeros(spec["n_expr"]))
        self._canonical_frames = None  # the neutral mesh's triangle frames, computed once

    def param_groups(self, settings) -> list[dict]:
        """The optimiser's groups (``settings``: the ``[mogaface]`` section): ``correction`` (encoder,
        fusion, head) and, with the texture attention, ``texture``. The bank is no parameter: it
        follows the corrections by its moving average."""
        groups = [{"params": [*self.encoder.parameters(), *self.fusion.parameters(), *self.head.parameters()],
                   "lr": settings.lr, "name": "correction"}]
        if self.texture is not None:
            groups.append({"params": list(self.texture.parameters()), "lr": settings.texture_lr, "name": "texture"})
        return groups

    @property
    def mode(self) -> str:
        return self.spec["mode"]

    # -- correction ---------------------------------------------------------------------------
    def correct(self, images: torch.Tensor, tracked_expr: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-view corrections ``(V, n_expr)`` and the timestamp's image feature ``(d,)``.

        ``multi`` fuses the views by cross-attention; ``single`` regresses each view alone.
        """
        features = self.encoder(images)
        fused = self.fusion(features) if self.mode == "multi" else features
        return self.head(fused, tracked_expr), fused.mean(0)

    @torch.no_grad()
    def observe_correction(self, delta: torch.Tensor, decay: float) -> None:
        """Running mean of the mesh corrections over training steps (its drift is penalised)."""
        self.correction_mean.mul_(decay).add_((1.0 - decay) * delta.detach())

    # -- texture ------------------------------------------------------------------------------
    def texture_offsets(self, gaussians, faces: torch.Tensor, params: dict):
        """Per-Gaussian local offsets for a frame's FLAME ``params`` (its corrected expression and
        pose), or None without the texture module."""
        if self.texture is None:
            return None
        if self._canonical_frames is None or len(self._canonical_frames.scale) != len(faces):
            self._canonical_frames = triangle_frames(self.canonical_vertices, faces)
        points = canonical_points(gaussians, self._canonical_frames, self.canonical_centre,
                                  self.canonical_half_extent)
        return self.texture(points, flame_code(params, int(self.spec["n_expr"])))

    # -- files --------------------------------------------------------------------------------
    def to_file_state(self) -> dict:
        return {"format": MODEL_FORMAT, "version": MODEL_VERSION, "spec": dict(self.spec),
                "timesteps": list(self.timesteps), "cameras": list(self.cameras),
                "state": {k: v.detach().clone() for k, v in self.state_dict().items()}}

    def save(self, path: str | os.PathLike) -> None:
        with atomic_path(pathlib.Path(path)) as tmp:
            save_torch_state(self.to_file_state(), tmp)

    @classmethod
    def from_file_state(cls, state: dict, source=None) -> "MoGaFace":
        if isinstance(state, dict) and state.get("format") == MODEL_FORMAT and state.get("version") == 1:
            state = _from_version_1(state, source)
        check_format(state, source, MODEL_FORMAT, MODEL_VERSION)
        tensors = state["state"]
        model = cls(state["spec"], state["timesteps"], state["cameras"], tensors["canonical_vertices"])
        model.load_state_dict(tensors)
        return model

    @classmethod
    def load(cls, path: str | os.PathLike) -> "MoGaFace":
        return cls.from_file_state(load_torch_state(path, "MoGaFace module file"), source=path)


_VERSION_1_FEATURES = ("default_feature", "default_feature_count", "timestep_features")


def _from_version_1(state: dict, source) -> dict:
    """A version-1 file without texture attention loads (its image-feature memory is dropped); one
    with texture attention cannot: that module read image features, which version 2 no longer has."""
    if state.get("spec", {}).get("texture"):
        raise InputError(source, "version", "a version-1 MoGaFace module file whose texture attention reads "
                                            "per-timestamp image features; this version conditions it on the "
                                            "FLAME code: train the run again")
    tensors = {k: v for k, v in state["state"].items() if k not in _VERSION_1_FEATURES}
    return {**state, "version": MODEL_VERSION, "state": tensors}
