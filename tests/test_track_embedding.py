"""Where MediaPipe's points sit on the procedural head (core/track/mediapipe_embedding.py): the stored
file is valid for the head's topology, and a frontal head shows its points where a face's are, in
MediaPipe's left/right order. scripts/derive_mediapipe_embedding.py derives the file again (--check)."""

import numpy as np
import pytest

from mogaface.core.data.head_preview import view_camera
from mogaface.core.errors import InputError
from mogaface.core.flame.landmarks import STATIC_IBUG, procedural_embedding
from mogaface.core.flame.procedural_mesh import build_mesh
from mogaface.core.io.npz import save_npz
from mogaface.core.track.mediapipe_embedding import (
    IRIS_CENTRES,
    MESH_COUNT,
    mediapipe_embedding,
    model_mediapipe_embedding,
    read_mediapipe_embedding,
)
from mogaface.core.track.mediapipe_ibug68 import IBUG68_FROM_MESH

# MediaPipe's eye contours (its FACEMESH_RIGHT_EYE and FACEMESH_LEFT_EYE): the subject's right eye, then the left
RIGHT_EYE = (33, 7, 163, 144, 145, 153, 154, 155, 133, 246, 161, 160, 159, 158, 157, 173)
LEFT_EYE = (263, 249, 390, 373, 374, 380, 381, 382, 362, 466, 388, 387, 386, 385, 384, 398)
SIZE = 512


@pytest.fixture(scope="module")
def mesh():
    return build_mesh()


def test_the_stored_embedding_is_valid_on_the_procedural_head(mesh):
    embedding = mediapipe_embedding()
    indices = embedding.ibug
    assert len(np.unique(indices)) == len(indices) and np.all(np.diff(indices) > 0)
    assert indices.min() >= 0 and set(IRIS_CENTRES) <= set(indices.tolist())
    assert (indices < MESH_COUNT).sum() >= 200 and indices[indices >= MESH_COUNT].tolist() == list(IRIS_CENTRES)
    assert embedding.faces.min() >= 0 and embedding.faces.max() < len(mesh.faces)
    assert np.all(embedding.barycentric >= 0) and np.allclose(embedding.barycentric.sum(1), 1)
    parts = mesh.part[mesh.faces[embedding.faces]]  # (L,3): each corner's part
    assert np.all(parts[indices < MESH_COUNT] == 0)  # mesh points on the skin
    assert np.all(parts[indices == 468] == 3) and np.all(parts[indices == 473] == 2)  # irises: −x eyeball, +x
    assert model_mediapipe_embedding(mesh.faces) is embedding
    assert model_mediapipe_embedding(mesh.faces[:-1]) is None  # another topology has none


def test_a_damaged_embedding_file_is_refused_by_name(tmp_path):
    path = tmp_path / "embedding.npz"
    save_npz(path, {"mediapipe": np.array([1, 1]), "faces": np.array([0, 1]), "barycentric": np.eye(3)[:2],
                    "n_faces": np.array(10)})
    with pytest.raises(InputError, match="embedding.npz.*distinct"):
        read_mediapipe_embedding(path)
    save_npz(path, {"mediapipe": np.array([1, 2]), "faces": np.array([0, 10]), "barycentric": np.eye(3)[:2],
                    "n_faces": np.array(10)})
    with pytest.raises(InputError, match="embedding.npz.*triangle indices"):
        read_mediapipe_embedding(path)


def test_a_frontal_head_shows_the_points_on_its_face_in_mediapipes_order(mesh):
    embedding = mediapipe_embedding()
    camera = view_camera(mesh.vertices, 0.0, 0.0, SIZE)
    uv, _ = camera.project(embedding.positions(mesh.vertices, mesh.faces))
    ibug = procedural_embedding()
    ibug_uv, _ = camera.project(ibug.positions(mesh.vertices, mesh.faces)[np.argsort(ibug.ibug)])
    # on the face: about between the jaw's ends (the temples lie a little wider), from the brows a face's
    # height up (the forehead) to the chin
    height, width = ibug_uv[8, 1] - ibug_uv[17:27, 1].min(), ibug_uv[16, 0] - ibug_uv[0, 0]
    assert np.all((uv[:, 0] > ibug_uv[0, 0] - 0.05 * width) & (uv[:, 0] < ibug_uv[16, 0] + 0.05 * width))
    assert np.all((uv[:, 1] > ibug_uv[17:27, 1].min() - height) & (uv[:, 1] < ibug_uv[8, 1] + 0.1 * height))
    # the subject's right eye (MediaPipe's RIGHT_EYE, iris 468) on the image's left
    x = dict(zip(embedding.ibug.tolist(), uv[:, 0]))
    right, left = [x[i] for i in RIGHT_EYE if i in x], [x[i] for i in LEFT_EYE if i in x]
    assert len(right) >= 8 and len(left) >= 8
    assert max(right) < SIZE / 2 < min(left)
    assert min(right) < x[468] < max(right) and min(left) < x[473] < max(left)


def test_the_points_the_ibug_mapping_names_lie_near_the_heads_own_ibug_points(mesh):
    """iBUG 17–67 through IBUG68_FROM_MESH (brows, nose, eyes, lips), at rest, within a centimetre."""
    embedding = mediapipe_embedding()
    ibug = procedural_embedding().subset(STATIC_IBUG)
    ibug_points = dict(zip(ibug.ibug.tolist(), ibug.positions(mesh.vertices, mesh.faces)))
    points = dict(zip(embedding.ibug.tolist(), embedding.positions(mesh.vertices, mesh.faces)))
    distance = [np.linalg.norm(points[IBUG68_FROM_MESH[k]] - ibug_points[k]) for k in STATIC_IBUG
                if IBUG68_FROM_MESH[k] in points]
    assert len(distance) >= 25 and max(distance) < 0.01, distance
