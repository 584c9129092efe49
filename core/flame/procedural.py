"""The procedural default head: a FLAME-layout model that can be shipped.

``build_head(subject, seed)`` returns the arrays of a FLAME model file (official
key names) plus UVs, a texture and component names. The licensed FLAME model
cannot be distributed, so avatars, synthetic captures and Blender shape keys all
run on this head. ``subject`` picks an identity (shape baked into the template,
skin/hair/iris colours, hairline); ``seed`` varies the random texture detail.
Equal arguments give bit-identical arrays.

The parts, built in ``procedural_mesh``/``procedural_ear``: the skin (a grid shaped
by the implicit head of ``procedural_sdf``, with slit eye and mouth openings), an
inner mouth bag with teeth, a lining inside each eye opening, two eyeballs and two
ears. ``procedural_rig`` holds weights, joints and pose correctives,
``procedural_blendshapes`` the identity and expression components and
``procedural_texture`` the painted texture.
"""

from __future__ import annotations

import functools

import numpy as np

from .procedural_blendshapes import EXPRESSION_NAMES, SHAPE_NAMES, expression_components, shape_components
from .procedural_mesh import build_mesh
from .procedural_rig import KINTREE_TABLE, joint_regressor, pose_correctives, skinning_weights
from .procedural_texture import paint_texture, subject_look

N_SHAPE = len(SHAPE_NAMES)
N_EXPR = len(EXPRESSION_NAMES)


def subject_shape(subject: int) -> np.ndarray:
    """Identity coefficients β of a subject (zeros for subject 0, the base head)."""
    if subject == 0:
        return np.zeros(N_SHAPE)
    rng = np.random.default_rng([104729, subject])
    return np.clip(rng.standard_normal(N_SHAPE), -2.2, 2.2)


def build_head(subject: int = 0, seed: int = 0) -> dict[str, np.ndarray]:
    """A FLAME-format head model for ``subject`` with texture detail drawn from ``seed`` (the
    caller's own copy: building one takes seconds, so a process builds each head once)."""
    if subject < 0 or seed < 0:
        raise ValueError("subject and seed must be non-negative integers")
    return {name: array.copy() for name, array in _built_head(int(subject), int(seed)).items()}


@functools.lru_cache(maxsize=4)
def _built_head(subject: int, seed: int) -> dict[str, np.ndarray]:
    mesh = build_mesh()
    base = mesh.vertices
    shapedirs = shape_components(mesh, base)
    template = base + shapedirs @ subject_shape(subject)
    exprdirs = expression_components(mesh, template)
    texture = paint_texture(mesh, template, subject_look(subject), np.random.default_rng([subject, seed, 31337]))
    return {
        "v_template": template,
        "f": mesh.faces.astype(np.int64),
        "shapedirs": np.concatenate([shapedirs, exprdirs], axis=2),
        "posedirs": pose_correctives(mesh, template),
        "J_regressor": joint_regressor(mesh, template),
        "weights": skinning_weights(mesh, template),
        "kintree_table": KINTREE_TABLE.copy(),
        "vt": mesh.vt.astype(np.float64),
        "ft": mesh.ft.astype(np.int64),
        "texture": texture,
        "expression_names": np.array(EXPRESSION_NAMES),
        "shape_names": np.array(SHAPE_NAMES),
        "n_shape": np.array(N_SHAPE, dtype=np.int64),
        "n_expr": np.array(N_EXPR, dtype=np.int64),
    }
