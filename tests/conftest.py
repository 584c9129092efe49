"""Shared fixtures: a tiny random FLAME-layout model and the procedural default head."""

import os
import tempfile

# Keep numba's cache and every user folder of the tests away from the real home.
os.environ.setdefault("MOGAFACE_CACHE_DIR", os.path.join(tempfile.gettempdir(), "mogaface-test-cache"))
# The tests run a worker per core (scripts/test.sh), each with as many threads as there are cores.
# An OpenMP thread with nothing to do (torch's and numba's) spins for a while on a core another
# worker needs: passive ones sleep at once. Read when torch or numba is first imported, here and in
# every child the tests start. On 2 cores: 228 -> 190 s on seven files that compute in the workers
# (two runs each), 218 -> 214 s on four that mostly wait for their child processes.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import pytest

# Seconds each of the longest files took on 2 cores (the mean of two whole runs, 2026-12-01).
# scripts/test.sh hands files to the workers in collection order (--no-loadscope-reorder), and
# this puts them longest first: pytest-xdist's own order (most tests first) left a few long files
# of one or two tests to the end, run by one worker while the other waited (78 s apart). A stale
# figure costs only that balance; the rest keep their order.
LONGEST_FILES = {
    "tests/test_blender_avatar.py": 147, "tests/test_refine_tracking.py": 102, "tests/test_landmarks.py": 82,
    "tests/test_train_distributed.py": 81, "tests/test_refiner.py": 69, "tests/test_bench_camera_search.py": 66,
    "tests/hostile/test_run_folder.py": 58, "tests/test_sources.py": 50, "tests/test_blender_footage.py": 46,
    "tests/hostile/test_corpus.py": 45, "tests/test_bench_converge.py": 42, "tests/test_train_run.py": 41,
    "tests/test_camera_colour.py": 33, "tests/test_one_avatar.py": 32, "tests/test_ablate.py": 32,
    "tests/test_generator.py": 30, "tests/test_track_pipeline.py": 28, "tests/test_camera_refine.py": 28,
    "tests/test_demo_tiny.py": 27, "tests/test_cycles_capture.py": 24, "tests/test_make_head_cli.py": 23,
    "tests/test_precompile.py": 22, "tests/test_camera_delays.py": 22, "tests/test_worker_start.py": 21,
}


def pytest_collection_modifyitems(items):
    items.sort(key=lambda item: -LONGEST_FILES.get(item.nodeid.split("::")[0], 0))  # stable: ties keep their order


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
