"""Tiny pickles that would build huge or broken objects (``pickle_bombs.py``) are refused by the
restricted unpickler, in a child process whose address space is capped well below what any of them
would take; real model pickles still load."""

import json
import pickle
import subprocess
import sys

import numpy as np
import pytest
from conftest import make_toy_model

from hostile import pickle_bombs as pb
from mogaface.core.errors import ModelFileError, UnsafePickleError
from mogaface.core.flame.model_file import read_model_file, write_model_file
from mogaface.core.flame.safe_pickle import load_model_pickle

CAP_BYTES = 1536 * 1024 ** 2  # every bomb asks for 2 GiB or more; an import of the reader needs ~0.4 GiB

# bomb -> what the refusal must say
EXPECTED = {
    "doubling_tuples_29": "counting a shared one each time it is reached",
    "doubling_lists_29": "counting a shared one each time it is reached",
    "nested_dtype_28": "numpy.dtype's arguments",
    "huge_memo_index": "memo slot 4294967280",
    "object_array_regrown": "refused an array of shape (1000000000,)",
    "scalar_without_data": "refused a numpy scalar",
    "deep_lists": "nested more than 64 deep",
    "self_containing_list": "it contains itself",
}

CHILD = r"""
import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[1]), int(sys.argv[1])))
from mogaface.core.errors import UnsafePickleError
from mogaface.core.flame.model_file import read_model_file
results = {}
for path in sys.argv[2:]:
    try:
        read_model_file(path)
        results[path] = ["loaded", ""]
    except Exception as error:
        results[path] = [type(error).__name__, str(error)]
print(json.dumps(results))
"""


def test_bombs_are_refused_with_bounded_memory(tmp_path):
    assert sorted(EXPECTED) == sorted(pb.ALL)
    paths = {}
    for name, build in pb.ALL.items():
        paths[name] = tmp_path / f"{name}.pkl"
        paths[name].write_bytes(build())
        assert paths[name].stat().st_size < 1024 or name == "deep_lists"
    result = subprocess.run([sys.executable, "-c", CHILD, str(CAP_BYTES), *map(str, paths.values())],
                            capture_output=True, text=True, timeout=300)  # a harness against hangs only
    assert result.returncode == 0, result.stderr
    outcome = json.loads(result.stdout)
    for name, path in paths.items():
        kind, message = outcome[str(path)]
        assert kind == "UnsafePickleError", (name, kind, message)
        assert message.startswith(f"{path}: ") and EXPECTED[name] in message, (name, message)


def test_a_shared_reference_bomb_is_refused_in_process(tmp_path):
    path = tmp_path / "m.pkl"
    path.write_bytes(pb.doubling_tuples(40))
    with pytest.raises(UnsafePickleError, match="m.pkl: refused the pickle: it holds more than"):
        load_model_pickle(path)


def test_a_wide_flat_list_within_the_budget_loads(tmp_path):
    """One byte an element without sharing stays within the budget; the model reader then judges it."""
    path = tmp_path / "m.pkl"
    path.write_bytes(pb.wide_list(100_000))
    assert len(load_model_pickle(path)["v_template"]) == 100_000
    with pytest.raises(ModelFileError, match="v_template.*expected a 2-D numeric array"):
        read_model_file(path)


def test_real_layouts_load_as_plain_arrays(tmp_path):
    """Our writer (chumpy ``Ch`` and scipy sparse layouts), and plain pickles of numeric, object and
    scalar values written by ``pickle`` itself, load to plain ``numpy.ndarray`` objects."""
    model = make_toy_model()
    model["names"] = np.array(["a", "bc"], dtype=object)
    model["scale"] = np.float64(2.5)
    model["shared"] = (model["weights"], model["weights"])
    path = tmp_path / "m.pkl"
    path.write_bytes(pickle.dumps(model, protocol=2))
    raw = load_model_pickle(path)
    assert type(raw["weights"]) is np.ndarray and np.array_equal(raw["weights"], model["weights"])
    assert raw["shared"][0] is raw["shared"][1]
    assert type(raw["names"]) is np.ndarray and list(raw["names"]) == ["a", "bc"]
    assert raw["scale"] == 2.5
    chumpy = tmp_path / "chumpy.pkl"
    write_model_file(chumpy, make_toy_model())
    assert np.array_equal(read_model_file(chumpy).weights, make_toy_model()["weights"])


@pytest.mark.parametrize("protocol", [2, 3, 4])
def test_every_protocol_of_a_float_array_loads(tmp_path, protocol):
    path = tmp_path / "m.pkl"
    array = np.arange(12.0).reshape(3, 4)
    path.write_bytes(pickle.dumps({"a": array, "b": array}, protocol=protocol))
    raw = load_model_pickle(path)
    assert np.array_equal(raw["a"], array) and raw["a"] is raw["b"]
