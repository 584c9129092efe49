"""Tracked FLAME parameters of a ``flame_param`` folder as keyframe columns for a head."""

from __future__ import annotations

import dataclasses
import os
import pathlib
import re

import numpy as np

from ..errors import InputError
from ..workflows.drive import thin_channel
from .axes import FRAME_OFFSET
from .head_rig import EXPRESSION_SLIDER_RANGE, POSE_PROPERTIES, fit_components


@dataclasses.dataclass
class Tracking:
    """Tracked FLAME parameters of a ``flame_param`` folder, one row per timestep."""

    folder: str
    timesteps: np.ndarray  # (T,) int
    params: dict  # name -> (T, n) float64: expr and the POSE_PROPERTIES names

    @property
    def frames(self) -> np.ndarray:
        return self.timesteps + FRAME_OFFSET


_DIGITS = re.compile(r"(\d+)$")


def read_tracking(folder) -> Tracking:
    """Read every ``*.npz`` of a ``flame_param`` folder (VHAP/GaussianAvatars layout).

    The timestep of ``00042.npz`` is 42 (the trailing digits of the name); files without
    digits take their position in name order. Only expression and pose are read: the
    identity (``shape``) belongs to the head they are applied to.
    """
    from ..run.folder import load_flame_file

    folder = pathlib.Path(folder)
    if not folder.is_dir():
        raise InputError(folder, None, "not a folder (expected a flame_param folder of .npz files)")
    files = sorted(folder.glob("*.npz"))
    if not files:
        raise InputError(folder, None, "no .npz files (expected a flame_param folder)")
    numbered = [_DIGITS.search(f.stem) for f in files]
    if all(numbered):
        timesteps = np.array([int(m.group(1)) for m in numbered])
        order = np.argsort(timesteps, kind="stable")
        files, timesteps = [files[i] for i in order], timesteps[order]
        if len(set(timesteps.tolist())) != len(timesteps):
            raise InputError(folder, None, "two files name the same timestep")
    else:
        timesteps = np.arange(len(files))
    names = ["expr", *POSE_PROPERTIES]
    rows = {name: [] for name in names}
    for path in files:
        params = load_flame_file(path)
        if "dynamic_offset" in params and np.abs(params["dynamic_offset"]).max() > 0:
            raise InputError(path, "dynamic_offset",
                             "per-timestep vertex offsets (VHAP's use_dynamic_offset) cannot be keyed as shape-key "
                             "values in Blender; render such tracking with 'python -m mogaface render', or track "
                             "without dynamic offsets")
        for name in names:
            if name not in params:
                raise InputError(path, name, "missing from the tracked parameters")
            rows[name].append(np.asarray(params[name], np.float64).reshape(-1))
    out = {}
    for name, values in rows.items():
        sizes = {len(v) for v in values}
        if len(sizes) != 1:
            raise InputError(folder, name, f"sizes differ between files: {sorted(sizes)}")
        out[name] = np.stack(values)
    return Tracking(os.fspath(folder), timesteps, out)


def keyframe_columns(frames, values, tolerance: float = 0.0) -> list[np.ndarray]:
    """``values (T,n)`` at ``frames (T,)`` → n flat ``[f0, v0, f1, v1, …]`` float32 arrays.

    The layout of ``FCurve.keyframe_points.foreach_set("co", …)``: one array per channel. With a
    ``tolerance``, each channel keeps only the keys :func:`thin_channel` keeps.
    """
    frames = np.asarray(frames, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64).reshape(len(frames), -1)
    columns = []
    for i in range(values.shape[1]):
        kept = thin_channel(values[:, i], tolerance, frames)
        columns.append(np.ascontiguousarray(np.stack([frames[kept], values[kept, i]], axis=1),
                                            dtype=np.float32).reshape(-1))
    return columns


def expression_keyframes(tracking: Tracking, n_expr: int) -> tuple[np.ndarray, str | None]:
    """The tracked expressions fitted to a head with ``n_expr`` keys, plus a warning if cut.

    Coefficients beyond the head's count are dropped (reported); missing ones are zero. Values
    outside the shape-key slider range are clamped by Blender, so they are reported too.
    """
    expr = tracking.params["expr"]
    notes = []
    if expr.shape[1] > n_expr:
        notes.append(f"the tracking has {expr.shape[1]} expression components, the head {n_expr}: extra ones ignored")
    fitted = fit_components(expr, n_expr)
    if np.abs(fitted).max(initial=0.0) > EXPRESSION_SLIDER_RANGE:
        notes.append(f"expression values beyond ±{EXPRESSION_SLIDER_RANGE:g} are clamped by Blender's sliders")
    return fitted, "; ".join(notes) or None


@dataclasses.dataclass
class TrackingChannels:
    """Keyframe columns for one head: per pose property its channels, per expression key one."""

    frames: np.ndarray  # (T,) scene frames
    pose: dict  # property name -> list of flat [f, v, …] arrays, one per vector index
    expressions: list  # one flat [f, v, …] array per expression shape key
    note: str | None = None


def tracking_channels(folder, n_expr: int, tolerance: float = 0.0) -> TrackingChannels:
    """A ``flame_param`` folder as keyframe columns for a head with ``n_expr`` expression keys
    (thinned within ``tolerance``: a key linear interpolation gives within it is dropped)."""
    tracking = read_tracking(folder)
    frames = tracking.frames
    expr, note = expression_keyframes(tracking, n_expr)
    pose = {prop: keyframe_columns(frames, tracking.params[name], tolerance)
            for name, (prop, _) in POSE_PROPERTIES.items()}
    return TrackingChannels(frames, pose, keyframe_columns(frames, expr, tolerance), note)
