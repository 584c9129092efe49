"""Cameras that disagree in colour: each training camera's affine colour, learned with the avatar.

A real rig's cameras differ in white balance and exposure, so one avatar cannot match every view:
the differences end up as colour noise in the avatar, or as view-dependent colour it invents. Each
training camera gets an affine map of the rendered foreground, ``c ↦ M·c + b``
(:func:`~..avatar.camera_colour.recolour`: every Gaussian's colour mapped, the background left as
it is), held as its change ``[M − I | b]`` from the identity, zero at the start; the loss compares
the recoloured render with the camera's image.

Gauge: the avatar's colours and the cameras' maps trade against each other (every camera's map
times ``G``, every Gaussian's colour times ``G⁻¹``, no image changes). After every optimiser step
the mean change over the training cameras is removed, so the **mean** camera sees the avatar's
own colours: no camera is privileged, and the avatar carries the rig's average colour, the best
guess for a camera that has no map of its own (the held-out one). Pinning one camera to the
identity would give the avatar that camera's error, and the held-out camera would pay it in full.
A penalty ``‖M − I‖² + ‖b‖²`` per view (``[cameras] colour_weight``) holds the maps at the
identity where the images hardly pin them: the directions of a camera that sees few distinct
colours, and the part of the head a camera sees nearly alone, where its map and the avatar's
colours trade as the whole rig's do. Too weak, the maps take up the avatar's own errors there.
"""

from __future__ import annotations

import pathlib

import torch
from torch import nn

from ..avatar.camera_colour import colour_entry, recolour
from ..errors import InputError
from ..io.atomic import write_json


class CameraColours(nn.Module):
    """One affine colour per camera (``camera_ids``), one ``(3, 4)`` parameter each, so Adam steps
    only the cameras a step rendered."""

    def __init__(self, camera_ids):
        super().__init__()
        self.ids = sorted(camera_ids)
        self.index = {cid: i for i, cid in enumerate(self.ids)}
        self.change = nn.ParameterList([nn.Parameter(torch.zeros(3, 4)) for _ in self.ids])

    def apply(self, camera_id: str, rgb: torch.Tensor, alpha: torch.Tensor, background) -> torch.Tensor:
        """A render of ``camera_id`` (over ``background``, coverage ``alpha``) in that camera's colours;
        unchanged for a camera without a map."""
        if camera_id not in self.index:
            return rgb
        return recolour(rgb, alpha, background, self.change[self.index[camera_id]])

    def penalty(self, camera_id: str) -> torch.Tensor:
        """``‖M − I‖² + ‖b‖²`` of the camera's map (zero for a camera without one)."""
        if camera_id not in self.index:
            return torch.zeros(())
        return self.change[self.index[camera_id]].square().sum()

    @torch.no_grad()
    def fix_gauge(self) -> None:
        """Remove the mean change over the cameras: the mean camera sees the avatar's own colours."""
        if not self.ids:
            return
        mean = torch.stack([p for p in self.change]).mean(0)
        for p in self.change:
            p.sub_(mean)

    def param_groups(self, cameras) -> list[dict]:
        """The optimiser's group ``cameras.colour`` (``cameras``: the ``[cameras]`` settings)."""
        return [{"params": list(self.change), "lr": cameras.colour_lr, "name": "cameras.colour"}]

    def values(self) -> dict[str, torch.Tensor]:
        """Camera id → its change ``[M − I | b]``, detached."""
        return {cid: self.change[i].detach().clone() for cid, i in self.index.items()}

    def state(self) -> dict:
        return {"ids": list(self.ids), "change": torch.stack([p.detach() for p in self.change]).clone()}

    @torch.no_grad()
    def start_from(self, values: dict) -> None:
        """Set the maps of the cameras ``values`` names (changes, e.g. a ``camera_colours.json``
        read); the others keep theirs."""
        for camera_id, change in values.items():
            if camera_id in self.index:
                self.change[self.index[camera_id]].copy_(torch.as_tensor(change, dtype=torch.float32))

    @torch.no_grad()
    def load(self, state: dict, source=None) -> None:
        if list(state.get("ids", [])) != self.ids:
            raise InputError(source, "colours.ids", "the checkpoint's camera colours are for other cameras")
        for p, value in zip(self.change, state["change"]):
            p.copy_(value)

    def write(self, path: pathlib.Path) -> None:
        """``RUN/camera_colours.json``: camera id → ``{"matrix", "offset"}``."""
        write_json(path, {cid: colour_entry(change.double().numpy()) for cid, change in self.values().items()})
