"""The trainer's MoGaFace part: build the modules, pose one training image, write the results.

Kept apart from :mod:`.trainer` so the baseline loop reads as before; with ``[mogaface] mode =
"off"`` nothing here runs.
"""

from __future__ import annotations

import copy
import pathlib

import torch

from ..correction.avatar import ModulatedAvatar, render_world
from ..correction.posing import world_with_offsets
from ..correction.training import CorrectionTraining
from ..data import layout
from ..io.npz import save_npz
from ..run.names import CORRECTED_DIR, MODULES_FILE


def build_mogaface(config, data, table, avatar) -> CorrectionTraining | None:
    """The MoGaFace modules of a run (None for the Freeze baseline)."""
    settings = config.mogaface
    if settings.mode == "off":
        return None
    with torch.no_grad():
        canonical = avatar.posed_vertices({"shape": table.shape[None],
                                           **({"static_offset": table.static_offset[None]}
                                              if table.static_offset is not None else {})})
    return CorrectionTraining(settings, data.frames, data.capture, table.timesteps, canonical,
                              int(table.expr.shape[1]), config.train.steps, seed=config.train.seed)


def mogaface_world(part: CorrectionTraining, avatar, table, frame, background, step: int, generator,
                   move_scene=None, vertex_shift=None):
    """Posed vertices, world Gaussians and the step's correction for one training image
    (``vertex_shift``: the camera's delay along the tracked motion, or None)."""
    params = table.params(frame.timestep_index)
    correction = part.step(frame, params["expr"][0], step, generator)
    if part.settings.rendered_weight:
        correction.rendered = part.rendered_loss(avatar, params, correction.inputs, background, generator)
    params = {**params, "expr": params["expr"] + correction.expr_delta[None]}
    vertices = avatar.posed_vertices(params)
    if vertex_shift is not None:
        vertices = vertices + vertex_shift
    faces = avatar.flame.faces
    offsets = part.model.texture_offsets(avatar.gaussians, faces, params)  # the corrected code
    world = world_with_offsets(avatar.gaussians, vertices, faces, offsets)
    return vertices, world if move_scene is None else move_scene(world), correction


def mogaface_render(part: CorrectionTraining, avatar, table, frame, camera, background, step: int, generator,
                    move_scene=None, vertex_shift=None):
    """Posed vertices, the render and the step's correction for one training image (``move_scene``:
    the camera refinement's scene motion for that camera, or None)."""
    vertices, world, correction = mogaface_world(part, avatar, table, frame, background, step, generator,
                                                 move_scene, vertex_shift)
    return vertices, render_world(world, camera, background), correction


@torch.no_grad()
def corrected_avatar(part: CorrectionTraining, avatar, table):
    """The corrected table and the modulated avatar (whose texture attention reads the corrected
    parameters): what the run draws once written, at any step of its training."""
    corrected = copy.deepcopy(table)
    for t in table.timesteps:
        row = table.row[t]
        corrected.expr[row] += part.timestep_correction(t, table.expr[row])
    return corrected, ModulatedAvatar(avatar, part.model)


def finish_mogaface(part: CorrectionTraining, avatar, table, root: pathlib.Path):
    """Save ``mogaface.pt`` and ``flame_param_corrected/``; returns :func:`corrected_avatar`'s pair."""
    corrected, modulated = corrected_avatar(part, avatar, table)
    part.model.save(root / MODULES_FILE)
    for t in table.timesteps:
        save_npz(root / CORRECTED_DIR / f"{t:05d}.npz", layout.batched_flame_params(corrected.numpy(t)))
    return corrected, modulated
