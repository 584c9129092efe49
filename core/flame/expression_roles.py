"""Expressions chosen by what they do: smile, blink, brow raise, pucker, the mouth components.

Our procedural head names its expression components; the released FLAME files do not
(their 100 components are principal components, ``expr000``… here). Features that want "a
smile" or "the lip components" pick by name when the model has names, and otherwise by
geometry, from the model itself:

- the mouth: FLAME's outer lip rings (vertex ids of FLAME's topology, see :mod:`.teeth`) on
  a 5023-vertex model, else the vertices the jaw joint mostly carries;
- the eyes: the rest-pose eye joints; eyelids are the skin vertices within 2.5 cm in front
  of them, brows the skin vertices 1.5–4 cm above them;
- **smile**: the component (and sign) that lifts the two mouth corners most;
  **pucker**: that pushes the mouth forward and pulls its corners inward most;
  **blink**: that lowers the eyelids most; **brow raise**: that lifts the brows most;
- **mouth components** (make-capture's speech): the components that move the mouth most.
"""

from __future__ import annotations

import re

import numpy as np

from .teeth import FLAME_VERTEX_COUNT, LIP_RING_LOWER, LIP_RING_UPPER, TEETH_VERTEX_COUNT

JAW, LEFT_EYE, RIGHT_EYE = 2, 3, 4
_DEFAULT_NAME = re.compile(r"^expr\d+$")
MOUTH_KEYWORDS = ("lip", "mouth", "smile", "pucker", "funnel", "press", "stretch")


def has_component_names(expression_names) -> bool:
    """Whether the model names its components (not only the ``exprNNN`` placeholders)."""
    return any(not _DEFAULT_NAME.match(name) for name in expression_names)


def _mouth_vertices(arrays) -> np.ndarray:
    if arrays.v_template.shape[0] in (FLAME_VERTEX_COUNT, FLAME_VERTEX_COUNT + TEETH_VERTEX_COUNT):
        return np.array(LIP_RING_UPPER + LIP_RING_LOWER)
    return np.flatnonzero(arrays.weights[:, JAW] > 0.5)


def _eye_regions(arrays) -> tuple[np.ndarray, np.ndarray]:
    """(eyelid vertices, brow vertices) around the rest-pose eye joints."""
    v = arrays.v_template
    joints = arrays.J_regressor @ v
    skin = arrays.weights[:, LEFT_EYE] + arrays.weights[:, RIGHT_EYE] < 0.5
    lids, brows = np.zeros(len(v), bool), np.zeros(len(v), bool)
    for eye in joints[[LEFT_EYE, RIGHT_EYE]]:
        d = v - eye
        lids |= skin & (np.linalg.norm(d, axis=1) < 0.025) & (d[:, 2] > 0)
        brows |= skin & (d[:, 1] > 0.015) & (d[:, 1] < 0.04) & (np.abs(d[:, 0]) < 0.025) & (d[:, 2] > 0)
    return np.flatnonzero(lids), np.flatnonzero(brows)


def _best(scores: np.ndarray, amount: float) -> np.ndarray:
    """An expression vector: the component with the largest |score|, signed so the score is positive."""
    expr = np.zeros(len(scores))
    k = int(np.argmax(np.abs(scores)))
    if scores[k] != 0:
        expr[k] = amount * np.sign(scores[k])
    return expr


def role_expression(arrays, role: str, amount: float = 1.5) -> np.ndarray:
    """``(n_expr,)`` coefficients that make ``role`` ("smile", "blink", "brow_raise", "pucker")."""
    names = list(arrays.expression_names)
    if has_component_names(names):
        keys = {"smile": ("smile", "cheek"), "blink": ("blink",), "brow_raise": ("brow_raise",),
                "pucker": ("pucker",)}[role]
        return np.array([amount if any(k in n.lower() for k in keys) else 0.0 for n in names])
    dirs = arrays.exprdirs  # (V,3,K)
    if role in ("smile", "pucker"):
        mouth = _mouth_vertices(arrays)
        if len(mouth) == 0:
            return np.zeros(len(names))
        x = arrays.v_template[mouth, 0]
        corners = mouth[[int(np.argmin(x)), int(np.argmax(x))]]
        outward = np.sign(arrays.v_template[corners, 0] - arrays.v_template[mouth, 0].mean())
        corner_out = (dirs[corners, 0, :] * outward[:, None]).sum(0)
        if role == "smile":
            scores = dirs[corners, 1, :].sum(0) + 0.5 * corner_out
        else:
            scores = dirs[mouth, 2, :].mean(0) - 0.5 * corner_out
        return _best(scores, amount)
    lids, brows = _eye_regions(arrays)
    region, sign = (lids, -1.0) if role == "blink" else (brows, 1.0)
    if len(region) == 0:
        return np.zeros(len(names))
    return _best(sign * dirs[region, 1, :].mean(0), amount)


def mouth_components(arrays, count: int = 8) -> list[int]:
    """The components that shape the mouth: by name, else the ``count`` that move it most."""
    names = list(arrays.expression_names)
    if has_component_names(names):
        found = [i for i, n in enumerate(names) if any(k in n.lower() for k in MOUTH_KEYWORDS)]
        return found or list(range(len(names)))
    mouth = _mouth_vertices(arrays)
    if len(mouth) == 0:
        return list(range(min(count, len(names))))
    motion = np.linalg.norm(arrays.exprdirs[mouth], axis=1).mean(0)
    return sorted(int(i) for i in np.argsort(-motion)[:count])
