"""What training reads from a capture: frames, images, background, FLAME parameters, extent, and
the warning a capture with a mirrored principal point gets."""

from __future__ import annotations

import os
import pathlib

import numpy as np
import torch

from ..data.capture import Capture, Frame
from ..data.capture_info import capture_background
from ..errors import MogafaceError

JOINTS = ("rotation", "neck_pose", "jaw_pose", "eyes_pose")


def principal_point_notes(capture, head) -> list[str]:
    """A warning when the masks fit the other reading of ``cy`` better (a capture written with
    ``cy`` from the top edge and no ``"cy_origin": "top"``): training would go on, misaligned.
    ``head``: the model file, or the avatar's model (loaded for this tracking already)."""
    from ..data.cy_check import check_cy

    try:
        report = check_cy(capture, head)
    except MogafaceError:  # an unreadable image: training reports it where it meets it, with a checkpoint
        return []
    return [f"{capture.root}: {report.line()}"] if report.verdict == "mirrored" else []


def camera_extent(cameras) -> float:
    """3DGS's scene extent: 1.1 × the largest distance of a camera centre from their mean. One
    camera (a tracked phone clip: the head moves, the camera stands) has no spread: then 1.1 × its
    distance from the world's origin, where the head is."""
    centres = np.stack([np.linalg.inv(c.w2c)[:3, 3] for c in cameras])
    radius = float(np.linalg.norm(centres - centres.mean(0), axis=1).max())
    if radius < 1e-6:
        radius = float(np.linalg.norm(centres.mean(0)))
    return 1.1 * max(radius, 1e-6)


class FlameTable(torch.nn.Module):
    """FLAME parameters of every training timestep as ``(T, n)`` tensors (the trainable form).

    Expressions, joint rotations and translation are parameters (optimised only when
    fine-tuning); shape and the static offset are shared by all timesteps and fixed.
    """

    def __init__(self, timesteps: list[int], stacked: dict[str, np.ndarray]):
        super().__init__()
        self.timesteps = list(timesteps)
        self.row = {t: i for i, t in enumerate(self.timesteps)}
        self.register_buffer("shape", torch.as_tensor(stacked["shape"][0], dtype=torch.float32))
        static = stacked.get("static_offset")
        self.register_buffer("static_offset", None if static is None else torch.as_tensor(static, dtype=torch.float32))
        dynamic = stacked.get("dynamic_offset")  # (T,V,3): VHAP's per-timestep offsets, fixed
        self.register_buffer("dynamic_offset", None if dynamic is None else torch.as_tensor(dynamic, dtype=torch.float32))
        for name in ("expr", *JOINTS, "translation"):
            setattr(self, name, torch.nn.Parameter(torch.as_tensor(stacked[name], dtype=torch.float32),
                                                   requires_grad=False))

    def trainable(self) -> dict[str, torch.nn.Parameter]:
        return {name: getattr(self, name) for name in ("expr", *JOINTS, "translation")}

    def param_groups(self, flame) -> list[dict]:
        """The optimiser's groups (``flame.<name>``) when ``flame.finetune`` (the ``[flame]``
        settings) is on, else none; marks the parameters trainable or fixed accordingly."""
        groups = []
        for name, value in self.trainable().items():
            value.requires_grad_(flame.finetune)
            if flame.finetune:
                rate = {"expr": flame.expression_lr, "translation": flame.translation_lr}.get(name, flame.joints_lr)
                groups.append({"params": [value], "lr": rate, "name": f"flame.{name}"})
        return groups

    def params(self, timestep: int | None = None) -> dict[str, torch.Tensor]:
        """The model's keyword arguments for one timestep (batch 1), or for all (batch T)."""
        rows = slice(None) if timestep is None else slice(self.row[timestep], self.row[timestep] + 1)
        out = {name: value[rows] for name, value in self.trainable().items()}
        batch = next(iter(out.values())).shape[0]
        out["shape"] = self.shape[None].expand(batch, -1)
        if self.static_offset is not None:
            out["static_offset"] = self.static_offset[None].expand(batch, -1, -1)
        if self.dynamic_offset is not None:
            out["dynamic_offset"] = self.dynamic_offset[rows]
        return out

    @property
    def n_vertices(self) -> int | None:
        """The vertex count the tracking's offsets describe (None without offsets)."""
        for offset in (self.static_offset, self.dynamic_offset):
            if offset is not None:
                return int(offset.shape[-2])
        return None

    def numpy(self, timestep: int) -> dict[str, np.ndarray]:
        """One timestep's parameters as the capture's ``(n,)`` float32 arrays."""
        out = {name: value[self.row[timestep]].detach().numpy().copy() for name, value in self.trainable().items()}
        out["shape"] = self.shape.numpy().copy()
        if self.static_offset is not None:
            out["static_offset"] = self.static_offset.numpy().copy()
        if self.dynamic_offset is not None:
            out["dynamic_offset"] = self.dynamic_offset[self.row[timestep]].numpy().copy()
        return out


class TrainingData:
    """The training frames of a capture with their images and FLAME parameters."""

    def __init__(self, root: str | os.PathLike, split: str = "train"):
        self.root = pathlib.Path(root).resolve()
        self.capture = Capture.open(self.root)
        self.frames: list[Frame] = self.capture.frames(split)
        self.timesteps = sorted({f.timestep_index for f in self.frames})
        self.background = capture_background(self.root)
        self.extent = camera_extent([self.capture.camera(f) for f in self.frames])

    def flame_table(self) -> FlameTable:
        return FlameTable(self.timesteps, self.capture.flame_params_stacked(self.timesteps))

    def check_counts(self, table: FlameTable, flame) -> None:
        """The head model ``flame`` has room for the table's coefficients; else the error names the
        first timestep's file (every timestep's has the same sizes, :meth:`Capture.flame_params_stacked`)."""
        first = table.timesteps[0]
        flame.check_counts(table.params(first), self.capture.flame_param_file(first))

    def target(self, frame: Frame) -> torch.Tensor:
        """The frame's image ``(H,W,3)``, already composited on :attr:`background`."""
        rgb, _ = self.capture.load_image(frame)
        return torch.from_numpy(np.array(rgb, dtype=np.float32))

    def split_summary(self) -> dict:
        out = {}
        for split, frames in self.capture.splits.items():
            out[split] = {
                "frames": len(frames),
                "timesteps": sorted({f.timestep_index for f in frames}),
                "cameras": sorted({f.camera_id for f in frames}),
            }
        return out


class FrameOrder:
    """Training frames in a fresh random order each epoch (every image seen once per epoch); its
    state (the epoch's order, the place in it) is part of a checkpoint."""

    def __init__(self, count: int):
        self.count = count
        self.order = torch.zeros(0, dtype=torch.long)
        self.position = 0

    def next(self, generator: torch.Generator) -> int:
        """The index of the next training frame, drawing a new order from ``generator`` at an epoch's end."""
        if self.position >= len(self.order):
            self.order = torch.randperm(self.count, generator=generator)
            self.position = 0
        self.position += 1
        return int(self.order[self.position - 1])

    def state(self) -> dict:
        return {"order": self.order.clone(), "position": self.position}

    def load_state(self, state: dict) -> None:
        self.order, self.position = state["order"].clone(), int(state["position"])
