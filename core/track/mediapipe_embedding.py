"""Where MediaPipe's face-mesh points and iris centres sit on the procedural head's mesh.

:func:`mediapipe_embedding` is a :class:`~mogaface.core.flame.landmarks.LandmarkEmbedding` whose
``ibug`` field holds MediaPipe indices instead of iBUG ones: the mesh points (0–467) found stable on
the procedural head, then the iris centres (468: the subject's right eye, 473: the left), each a
triangle of the head's mesh and barycentric weights. It belongs to the procedural head's topology
(every subject shares it); :func:`model_mediapipe_embedding` gives it only to a model with those
triangles (FLAME's own mesh, 5023 vertices and 9976 triangles, is another).

It was made on renders of the procedural head, not taken from anyone's published embedding:
``scripts/derive_mediapipe_embedding.py`` triangulates each point from many views of several poses,
snaps it to the skin and keeps the points that agree across subjects and poses (see
``docs/tracking.md``); the iris centres are the eyeballs' front poles. The file is
``mediapipe_embedding.npz`` beside this module.
"""

from __future__ import annotations

import functools
import os
import pathlib

import numpy as np

from ..errors import InputError
from ..flame.landmarks import LandmarkEmbedding
from ..io.npz import load_npz

EMBEDDING_FILE = pathlib.Path(__file__).with_name("mediapipe_embedding.npz")
MESH_COUNT = 468
IRIS_CENTRES = (468, 473)


def read_mediapipe_embedding(path: str | os.PathLike = EMBEDDING_FILE) -> LandmarkEmbedding:
    """The embedding in ``path`` (keys ``mediapipe``, ``faces``, ``barycentric``, ``n_faces``), checked."""
    entries = load_npz(path)
    for key in ("mediapipe", "faces", "barycentric", "n_faces"):
        if key not in entries:
            raise InputError(path, key, "missing from the MediaPipe embedding")
    indices = np.asarray(entries["mediapipe"]).astype(np.int64)
    if len(np.unique(indices)) != len(indices) or indices.min() < 0 or indices.max() > IRIS_CENTRES[1]:
        raise InputError(path, "mediapipe", "expected distinct MediaPipe indices in [0, 478)")
    embedding = LandmarkEmbedding(np.asarray(entries["faces"]).astype(np.int64),
                                  np.asarray(entries["barycentric"], np.float64), indices)
    if embedding.barycentric.shape != (len(indices), 3) or embedding.faces.shape != indices.shape:
        raise InputError(path, "barycentric", f"expected {len(indices)} triangles and ({len(indices)}, 3) weights")
    return embedding.check(int(entries["n_faces"]), path)


@functools.lru_cache(maxsize=1)
def mediapipe_embedding() -> LandmarkEmbedding:
    """The stored embedding (MediaPipe indices in ``ibug``), on the procedural head's topology."""
    return read_mediapipe_embedding(EMBEDDING_FILE)


def model_mediapipe_embedding(faces: np.ndarray) -> LandmarkEmbedding | None:
    """The embedding for a model with triangles ``faces`` (F,3): the stored one when they are the
    procedural head's, else None."""
    from ..flame.procedural_mesh import build_mesh

    own = build_mesh().faces
    return mediapipe_embedding() if faces.shape == own.shape and np.array_equal(faces, own) else None
