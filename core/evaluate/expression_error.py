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
from ..errors import InputError
from ..io.files import file_inside
from ..flame.model import FlameModel
from .run_folder import MOTION_KEYS, RunFolder, capture_info, load_flame_file


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


def expression_errors(run_dir: str | os.PathLike, capture: str | os.PathLike | None = None) -> dict:
    """``{"timesteps", "expr_rmse_*", "expr_vertex_mm_*", "vertex_mm_*"}`` with ``*`` tracked and corrected."""
    run = RunFolder(run_dir, capture)
    cap = run.open_capture()
    truth_dir = capture_info(cap.root).get("ground_truth", {}).get("flame_param")
    if not truth_dir or not file_inside(cap.root, truth_dir, cap.root / "capture_info.json",
                                        "ground_truth.flame_param").is_dir():
        raise InputError(cap.root, "ground_truth.flame_param", "the capture carries no true parameters")
    folder = pathlib.Path(run.avatar_path).parent
    head = file_inside(folder, run.info.get("head_file", "head.pkl"), folder / "run.json", "head_file")
    model = FlameModel.load(head)
    expr = {"tracked": [], "corrected": []}
    vertex = {"tracked": [], "corrected": []}
    expr_vertex = {"tracked": [], "corrected": []}
    for timestep in run.trained_timesteps:
        truth = load_flame_file(cap.root / truth_dir / f"{timestep:05d}.npz")
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
