"""How close a run's expressions are to the truth, for synthetic captures that carry it.

Synthetic captures keep the true parameters in ``flame_param_gt/`` beside the tracked ones. Over
the run's training timesteps this reports, for the tracked parameters (before) and the run's own
``flame_param/`` (after correction): the RMSE of the expression coefficients, the mean vertex
distance (mm) of the expression alone (the true pose with the tracked or corrected expression, so
pose errors, which an expression correction cannot fix, do not hide it) and of the whole posed mesh.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np
import torch

from ..data import layout
from ..data.capture_info import capture_info
from ..errors import InputError
from ..flame.model import FlameModel
from ..io.files import file_inside
from ..run.folder import MOTION_KEYS, RunFolder, load_flame_file


def _mesh(model: FlameModel, params: dict[str, np.ndarray]) -> np.ndarray:
    flame = {k: v for k, v in params.items() if k in layout.FLAME_KEYS}  # no texture feature or the like
    with torch.no_grad():
        return model(**{k: torch.as_tensor(v, dtype=torch.float32)[None] for k, v in flame.items()})[0].numpy()


def _distance_mm(mesh: np.ndarray, truth: np.ndarray) -> float:
    return float(np.linalg.norm(mesh - truth, axis=1).mean() * 1000.0)


def frame_errors(model: FlameModel, params: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> dict[str, float]:
    """How far one frame's motion parameters are from the truth, with the truth's identity in both
    meshes (so only motion counts): the expression coefficients' RMSE, the mean vertex distance (mm)
    of the expression alone (true pose) and of the whole posed mesh (every motion parameter)."""
    true_mesh = _mesh(model, truth)
    motion = {**truth, **{k: params[k] for k in MOTION_KEYS if k in params}}
    return {
        "expr_rmse": float(np.sqrt(np.mean(np.square(params["expr"] - truth["expr"])))),
        "expr_vertex_mm": _distance_mm(_mesh(model, {**truth, "expr": params["expr"]}), true_mesh),
        "vertex_mm": _distance_mm(_mesh(model, motion), true_mesh),
    }


def truth_gauge(run: RunFolder, truth_for) -> dict[str, np.ndarray]:
    """The avatar's gauge: per motion parameter, the mean of (the run's parameters − the truth,
    ``truth_for(timestep)``) over the run's training timesteps. An avatar absorbs the tracker's
    constant bias in training and no image can show it, so parameter errors are also given against
    the truth plus this offset (``*_gauge``; docs/notebook/2026-11-26-multiview-refiner.md). Empty
    for a run without training timesteps."""
    trained = list(run.trained_timesteps)
    if not trained:
        return {}
    pairs = [(run.flame_params(t), truth_for(t)) for t in trained]
    return {k: np.mean([np.asarray(own[k], np.float64) - true[k] for own, true in pairs], axis=0).astype(np.float32)
            for k in MOTION_KEYS if all(k in own and k in true for own, true in pairs)}


def in_gauge(truth: dict[str, np.ndarray], gauge: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The truth moved by the avatar's gauge (:func:`truth_gauge`)."""
    return {**truth, **{k: (truth[k] + v).astype(np.float32) for k, v in gauge.items()}}


def gauge_errors(model: FlameModel, params: dict[str, np.ndarray], truth: dict[str, np.ndarray],
                 gauge: dict[str, np.ndarray]) -> dict[str, float]:
    """:func:`frame_errors`' mesh distances against the truth in the avatar's gauge, as
    ``vertex_mm_gauge`` and ``expr_vertex_mm_gauge``."""
    errors = frame_errors(model, params, in_gauge(truth, gauge))
    return {"vertex_mm_gauge": errors["vertex_mm"], "expr_vertex_mm_gauge": errors["expr_vertex_mm"]}


def truth_folder(capture) -> pathlib.Path | None:
    """A synthetic capture's folder of true parameters (``flame_param_gt/``), or None (real captures)."""
    truth_dir = capture_info(capture.root).get("ground_truth", {}).get("flame_param")
    if not truth_dir:
        return None
    folder = file_inside(capture.root, truth_dir, capture.root / "capture_info.json", "ground_truth.flame_param")
    return folder if folder.is_dir() else None


def _run_model(run: RunFolder) -> FlameModel:
    folder = pathlib.Path(run.avatar_path).parent
    return FlameModel.load(file_inside(folder, run.info.get("head_file", run.head_path().name), run.run_json_path, "head_file"))


def tracking_errors(run: RunFolder, capture, sources: dict) -> dict | None:
    """How far each source's parameters (``name -> params_for(timestep)``) are from the truth over
    every timestep of a synthetic capture, grouped into the run's training timesteps and the
    others; None without a truth. ``vertex_mm`` (whole mesh) and ``expr_vertex_mm`` (expression
    alone) are given raw and ``*_gauge``: against the truth plus the mean offset of the run's
    fine-tuned parameters from it, the constant tracker bias an avatar absorbs in training and that
    no image can show (docs/notebook/2026-11-26-multiview-refiner.md, "The multi-view refiner")."""
    folder = truth_folder(capture)
    if folder is None:
        return None
    model = _run_model(run)
    truth = {t: load_flame_file(folder / f"{t:05d}.npz") for t in capture.timesteps}
    trained = set(run.trained_timesteps)
    gauge = truth_gauge(run, truth.__getitem__)
    out = {}
    for name, params_for in sources.items():
        rows = {"training": [], "unseen": []}
        for timestep, true in truth.items():
            params = params_for(timestep)
            raw, shifted = frame_errors(model, params, true), gauge_errors(model, params, true, gauge)
            rows["training" if timestep in trained else "unseen"].append(
                [raw["vertex_mm"], raw["expr_vertex_mm"], shifted["vertex_mm_gauge"], shifted["expr_vertex_mm_gauge"]])
        out[name] = {group: {"timesteps": len(values), **dict(zip(
            ("vertex_mm", "expr_vertex_mm", "vertex_mm_gauge", "expr_vertex_mm_gauge"),
            np.mean(values, axis=0).tolist()))} for group, values in rows.items() if values}
    return out


def expression_errors(run_dir: str | os.PathLike, capture: str | os.PathLike | None = None) -> dict:
    """``{"timesteps", "expr_rmse_*", "expr_vertex_mm_*", "vertex_mm_*"}`` with ``*`` tracked and corrected."""
    run = RunFolder(run_dir, capture)
    cap = run.open_capture()
    folder = truth_folder(cap)
    if folder is None:
        raise InputError(cap.root, "ground_truth.flame_param", "the capture carries no true parameters")
    model = _run_model(run)
    expr = {"tracked": [], "corrected": []}
    vertex = {"tracked": [], "corrected": []}
    expr_vertex = {"tracked": [], "corrected": []}
    for timestep in run.trained_timesteps:
        truth = load_flame_file(folder / f"{timestep:05d}.npz")
        true_mesh = _mesh(model, truth)
        for name, params in (("tracked", cap.flame_params(timestep)), ("corrected", run.flame_params(timestep))):
            expr[name].append(params["expr"] - truth["expr"])
            vertex[name].append(_distance_mm(_mesh(model, params), true_mesh))
            expr_vertex[name].append(_distance_mm(_mesh(model, {**truth, "expr": params["expr"]}), true_mesh))
    if not run.trained_timesteps:
        raise InputError(run.flame_param_dir, None, "the run holds no FLAME parameters")
    return {
        "timesteps": len(run.trained_timesteps),
        "expr_rmse_tracked": float(np.sqrt(np.mean(np.square(expr["tracked"])))),
        "expr_rmse_corrected": float(np.sqrt(np.mean(np.square(expr["corrected"])))),
        "expr_vertex_mm_tracked": float(np.mean(expr_vertex["tracked"])),
        "expr_vertex_mm_corrected": float(np.mean(expr_vertex["corrected"])),
        "vertex_mm_tracked": float(np.mean(vertex["tracked"])),
        "vertex_mm_corrected": float(np.mean(vertex["corrected"])),
    }
