"""Benchmark of one evaluation of the tracker's fit at a clip's scale: milliseconds for the forward and
backward pass of each piece, against references in the same run.

A 20-s clip at 30 fps is 600 frames. Each L-BFGS evaluation of the photometric stage poses the
landmarks' vertices (:class:`~mogaface.core.track.head.LandmarkHead` on the procedural head's 400
landmarks) and 1 500 skin points in every frame, and compares the skin's brightness between
frame pairs (:class:`~mogaface.core.track.photometric.BrightnessAgreement`, gaps 1, 5, 20, 60, 150).
References: the library's :func:`~mogaface.core.flame.lbs.linear_blend_skinning` on the same
vertices (a 4×4 matrix blended per vertex and frame), and the whole model posed then read at the
points. The heads pose in the fit's precision (:data:`~mogaface.core.track.fit.POSED`, float32,
from float64 parameters); every head's points are checked against the whole model's in float64
(to a fraction of a micrometre).
Medians of ``repeats`` runs after one warm-up, with the load average.
"""

from __future__ import annotations

import os
import pathlib
import platform
import tempfile

from .timing import median_ms

FRAMES, SKIN_POINTS, IMAGE = 600, 1500, (512, 288)


def _parameters(model, frames: int):
    import torch

    generator = torch.Generator().manual_seed(0)
    sizes = {"shape": (1, model.n_shape, 0.5), "expr": (frames, model.n_expr, 0.5), "rotation": (frames, 3, 0.2),
             "jaw_pose": (frames, 3, 0.1), "translation": (frames, 3, 0.01), "eyes_pose": (frames, 6, 0.1)}
    return {name: (torch.randn(rows, columns, generator=generator, dtype=torch.float64) * scale).requires_grad_(True)
            for name, (rows, columns, scale) in sizes.items()}


def _order(params: dict) -> list:
    return [params[name] for name in ("shape", "expr", "rotation", "jaw_pose", "translation", "eyes_pose")]


def _blended_skinning(head, model):
    """The reference: the library's skinning on the head's vertices, then its landmarks' corners."""
    import torch

    from mogaface.core.flame.lbs import axis_angle_to_matrix, linear_blend_skinning

    ids = torch.as_tensor(head.vertex_ids)
    weights = model.lbs_weights.double()[ids]
    shapedirs, exprdirs = model.shapedirs.double()[ids], model.exprdirs.double()[ids]
    posedirs = model.posedirs.double().reshape(model.posedirs.shape[0], -1, 3)[:, ids].reshape(model.posedirs.shape[0], -1)

    def pose(shape, expr, rotation, jaw, translation, eyes):
        frames = expr.shape[0]
        zero = torch.zeros(frames, 3, dtype=expr.dtype)
        shaped = (model.v_template.double()[ids] + torch.einsum("vck,bk->bvc", shapedirs, shape)
                  + torch.einsum("vck,bk->bvc", exprdirs, expr))
        joints = (head.joints_template + torch.einsum("jck,bk->bjc", head.joints_shape, shape)
                  + torch.einsum("jck,bk->bjc", head.joints_expr, expr))
        rotations = axis_angle_to_matrix(torch.cat([rotation, zero, jaw, eyes], 1).reshape(frames, 5, 3))
        posed = linear_blend_skinning(shaped, rotations, joints, model.parents, weights, posedirs)
        points = posed.index_select(1, head.corner).reshape(frames, *head.barycentric.shape[:2], 3)
        return (points * head.barycentric).sum(-2) + translation[:, None, :]
    return pose


def run(threads: int = 2, quick: bool = False) -> dict:
    import numpy as np
    import torch

    from mogaface.core.data.generator import write_head_model
    from mogaface.core.flame.model import FlameModel
    from mogaface.core.track.fit import POSED
    from mogaface.core.track.head import LandmarkHead
    from mogaface.core.track.photometric import (
        BrightnessAgreement,
        PhotometricSettings,
        frame_pairs,
        skin_points,
        vertex_embedding,
    )
    from mogaface.core.track.pipeline import _embedding

    torch.set_num_threads(threads)
    repeats = 3 if quick else 9

    def timed(call) -> float:
        return round(median_ms(call, repeats), 1)

    with tempfile.TemporaryDirectory() as folder:
        model = FlameModel.load(write_head_model(pathlib.Path(folder), 0, 0), dtype=torch.float64)
    params = _parameters(model, FRAMES)
    with torch.no_grad():
        whole = model(**{name: value.detach() for name, value in params.items()})
    faces = model.faces.numpy()
    heads = {"landmarks": _embedding(model)[0], "skin": vertex_embedding(faces, skin_points(model, SKIN_POINTS, 0))}
    report = {}
    for name, embedding in heads.items():
        head = LandmarkHead(model, embedding, dtype=POSED)
        reference = _blended_skinning(LandmarkHead(model, embedding), model)  # in float64
        error = float((head(*_order(params)).detach() - embedding.positions(whole, faces)).abs().max())
        times = {label: timed(lambda pose=pose: pose(*_order(params)).square().sum().backward())
                 for label, pose in (("head", head), ("blended_skinning", reference))}
        whole_ms = timed(lambda: embedding.positions(model(**params), faces).square().sum().backward())
        report[name] = {"points": len(embedding.faces), "vertices": len(head.vertex_ids), "fwd_bwd_ms": times["head"],
                        "blended_skinning_ms": times["blended_skinning"], "whole_model_ms": whole_ms,
                        "over_blended_skinning": round(times["head"] / times["blended_skinning"], 3),
                        "max_error_m": error}
    rng = np.random.default_rng(0)
    images = rng.random((FRAMES, *IMAGE)).astype(np.float32)
    seen = rng.random((FRAMES, SKIN_POINTS)) < 0.5
    pairs = frame_pairs(np.zeros(FRAMES), PhotometricSettings().gaps)
    normals = rng.normal(size=(FRAMES, SKIN_POINTS, 3))  # what a video's shading is removed along
    agreement = BrightnessAgreement(images, seen, PhotometricSettings().resolved(photos=False), pairs, normals)
    pixels = torch.as_tensor(rng.uniform(20, 260, (FRAMES, SKIN_POINTS, 2)), dtype=POSED).requires_grad_(True)
    report["brightness_agreement"] = {"pairs": len(pairs), "fwd_bwd_ms": timed(lambda: agreement(pixels).backward())}
    return {
        "frames": FRAMES,
        "threads": threads,
        "repeats": repeats,
        "pieces": report,
        "load_average": open("/proc/loadavg").read().split()[:3] if os.path.exists("/proc/loadavg") else None,
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
    }
