"""Shared fixtures: a tiny random FLAME-layout model and the procedural default head."""

import os
import tempfile

# Keep numba's cache and every user folder of the tests away from the real home.
os.environ.setdefault("MOGAFACE_CACHE_DIR", os.path.join(tempfile.gettempdir(), "mogaface-test-cache"))

import numpy as np
import pytest


def make_toy_model(n_vertices=40, n_shape=4, n_expr=3, seed=0):
    """A small random model in the FLAME file layout (5 joints, FLAME's kinematic tree)."""
    rng = np.random.default_rng(seed)
    weights = rng.random((n_vertices, 5)) ** 3
    weights /= weights.sum(1, keepdims=True)
    regressor = rng.random((5, n_vertices))
    regressor /= regressor.sum(1, keepdims=True)
    return {
        "v_template": rng.normal(scale=0.1, size=(n_vertices, 3)),
        "f": rng.integers(0, n_vertices, size=(2 * n_vertices, 3)).astype(np.int64),
        "shapedirs": rng.normal(scale=0.01, size=(n_vertices, 3, n_shape + n_expr)),
        "posedirs": rng.normal(scale=0.01, size=(n_vertices, 3, 36)),
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": np.array([[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]], dtype=np.int64),
        "n_shape": np.int64(n_shape),
    }


@pytest.fixture
def toy_model():
    return make_toy_model()


@pytest.fixture(scope="session")
def procedural_head():
    """The default procedural head's arrays (built once per test session)."""
    from mogaface.core.flame.procedural import build_head

    return build_head(subject=0, seed=0)


@pytest.fixture(scope="session")
def procedural_head_pkl(procedural_head, tmp_path_factory):
    from mogaface.core.flame.model_file import write_model_file

    path = tmp_path_factory.mktemp("head") / "head.pkl"
    write_model_file(path, procedural_head)
    return path


@pytest.fixture(scope="session")
def handheld(tmp_path_factory, procedural_head_pkl):
    """A tiny synthetic phone clip (``make-footage``: 64x112, 12 frames, handheld) and its truth aside."""
    from mogaface.core.cli import main

    out = tmp_path_factory.mktemp("handheld")
    code = main(["make-footage", str(out), "--size", "64x112", "--seconds", "0.4", "--supersample", "1",
                 "--novel-views", "2", "--novel-every", "6", "--novel-size", "32", "--seed", "3", "--quiet",
                 "--model", str(procedural_head_pkl), "--contact-sheet", str(out / "sheet.png")])
    assert code == 0
    return out
