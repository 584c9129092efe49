"""Unsynchronised cameras: each training camera's time offset against the tracking.

A rig whose cameras are not triggered together sees the head at a slightly different moment in
each view, while the tracking gives one mesh per timestep. A camera that takes its images ``δ``
timesteps late sees the head about where the tracked motion puts it ``δ`` timesteps on: its mesh
is moved along the parabola through the meshes of the timestep and its two neighbours in the same
sequence, ``δ·v + δ²/2·a`` (``v``, ``a``: their central first and second differences; a straight
line to the one neighbour at a sequence's ends). The parabola follows a motion that bends between
timesteps, which the velocity alone misses by ``δ²/2·a``. One number per camera, shared by
every timestep: it carries over to frames no training step saw, which a free correction per image
would not. The motion is held fixed (no gradient): only ``δ`` learns from it.
"""

from __future__ import annotations

import math
import pathlib
from typing import Callable

import torch
from torch import nn

from ..errors import InputError
from ..io.atomic import write_json
from ..io.jsonfile import read_json_object


class CameraDelays(nn.Module):
    """One delay per camera (``camera_ids``), one parameter each, so Adam steps only the cameras a
    step rendered. ``sequences``: the timesteps of each sequence (neighbours are taken within one)."""

    def __init__(self, camera_ids, timesteps, sequences: dict[str, list[int]] | None = None):
        super().__init__()
        self.ids = sorted(camera_ids)
        self.index = {cid: i for i, cid in enumerate(self.ids)}
        self.delay = nn.ParameterList([nn.Parameter(torch.zeros(())) for _ in self.ids])
        self.neighbours = _neighbours(sorted(timesteps), sequences or {})

    def shift(self, camera_id: str, timestep: int, posed: Callable[[int], torch.Tensor]) -> torch.Tensor | None:
        """The move of ``camera_id``'s mesh at ``timestep`` (``posed(t)``: a timestep's vertices), or
        None when the camera has no delay or the timestep no neighbour."""
        if camera_id not in self.index or timestep not in self.neighbours:
            return None
        before, after = self.neighbours[timestep]
        delay = self.delay[self.index[camera_id]]
        ahead, behind = posed(after).detach(), posed(before).detach()
        velocity = (ahead - behind) / float(after - before)
        if after - before == 1:  # one neighbour: the line to it
            return delay * velocity
        bend = ahead - 2.0 * posed(timestep).detach() + behind
        return delay * velocity + 0.5 * delay * delay * bend

    def param_groups(self, cameras) -> list[dict]:
        """The optimiser's group ``cameras.delay`` (``cameras``: the ``[cameras]`` settings)."""
        return [{"params": list(self.delay), "lr": cameras.delay_lr, "name": "cameras.delay"}]

    def values(self) -> dict[str, float]:
        return {cid: float(self.delay[i].detach()) for cid, i in self.index.items()}

    def state(self) -> dict:
        return {"ids": list(self.ids), "delay": torch.stack([p.detach() for p in self.delay]).clone()}

    @torch.no_grad()
    def start_from(self, values: dict[str, float]) -> None:
        """Set the delays of the cameras ``values`` names (e.g. a ``camera_delays.json``); the
        others keep theirs."""
        for camera_id, value in values.items():
            if camera_id in self.index:
                self.delay[self.index[camera_id]].fill_(value)

    @torch.no_grad()
    def load(self, state: dict, source=None) -> None:
        if list(state.get("ids", [])) != self.ids:
            raise InputError(source, "delays.ids", "the checkpoint's camera delays are for other cameras")
        for p, value in zip(self.delay, state["delay"]):
            p.copy_(value)

    def write(self, path: pathlib.Path) -> None:
        write_json(path, self.values())


def delayed_views(capture, avatar, path: pathlib.Path) -> Callable | None:
    """For scoring: frame → the move of its mesh by the delay a run learned for its camera (``path``,
    a ``camera_delays.json``), the motion taken from the capture's tracking, or None (no delay for
    that camera, no neighbour). None without the file."""
    from ..avatar.avatar import flame_params_to_torch

    if not path.exists():
        return None
    values = read_delays(path)
    delays = CameraDelays(values, capture.timesteps, capture.sequences)
    delays.start_from(values)
    meshes: dict[int, torch.Tensor] = {}

    def posed(timestep: int) -> torch.Tensor:
        if timestep not in meshes:
            if len(meshes) > 8:  # frames come timestep by timestep: keep the neighbourhood only
                meshes.clear()
            meshes[timestep] = avatar.posed_vertices(flame_params_to_torch(capture.flame_params(timestep)))
        return meshes[timestep]

    def shift(frame) -> torch.Tensor | None:
        with torch.no_grad():
            return delays.shift(frame.camera_id, frame.timestep_index, posed)

    return shift


def read_delays(path: pathlib.Path) -> dict[str, float]:
    """A ``camera_delays.json``: camera id → delay in timesteps."""
    values = read_json_object(path)
    for camera_id, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise InputError(path, camera_id, f"expected a delay in timesteps (a finite number), got {value!r}")
    return {str(k): float(v) for k, v in values.items()}


def _neighbours(timesteps: list[int], sequences: dict[str, list[int]]) -> dict[int, tuple[int, int]]:
    """Timestep → the two timesteps its velocity is taken between: its neighbours one step away in
    the same sequence (itself where it is the first or the last there present)."""
    sequence_of = {t: name for name, members in sequences.items() for t in members}
    present = set(timesteps)
    out = {}
    for t in timesteps:
        same = [u for u in (t - 1, t + 1) if u in present and sequence_of.get(u) == sequence_of.get(t)]
        before = t - 1 if t - 1 in same else t
        after = t + 1 if t + 1 in same else t
        if before != after:
            out[t] = (before, after)
    return out
