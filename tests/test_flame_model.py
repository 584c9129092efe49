"""FLAME-format loading and the LBS evaluator, against an independent numpy implementation."""

import os
import pickle
import re

import numpy as np
import pytest
import torch
from conftest import make_toy_model
from flame_reference import flame_vertices

from mogaface.core.errors import ModelFileError, UnsafePickleError
from mogaface.core.flame.model import FlameModel
from mogaface.core.flame.model_file import read_model_file, write_model_file


def random_params(model, rng, batch=None, scale=0.4):
    shape = () if batch is None else (batch,)
    return {
        "shape": rng.normal(size=shape + (model.n_shape,)),
        "expr": rng.normal(size=shape + (model.n_expr,)),
        "rotation": rng.normal(scale=scale, size=shape + (3,)),
        "neck_pose": rng.normal(scale=scale, size=shape + (3,)),
        "jaw_pose": rng.normal(scale=scale, size=shape + (3,)),
        "eyes_pose": rng.normal(scale=scale, size=shape + (6,)),
        "translation": rng.normal(scale=0.05, size=shape + (3,)),
    }


def reference(model, p, static_offset=None):
    a = model.arrays
    arrays = dict(
        v_template=a.v_template,
        shapedirs=a.shapedirs,
        exprdirs=a.exprdirs,
        posedirs=a.posedirs,
        J_regressor=a.J_regressor,
        weights=a.weights,
        parents=a.parents,
    )
    return flame_vertices(
        arrays,
        p["shape"],
        p["expr"],
        p["rotation"],
        p["neck_pose"],
        p["jaw_pose"],
        p["eyes_pose"],
        p["translation"],
        static_offset,
    )


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_lbs_matches_independent_numpy_on_procedural_pkl(procedural_head_pkl, dtype):
    model = FlameModel.load(procedural_head_pkl, dtype=dtype)
    rng = np.random.default_rng(7)
    batch = [random_params(model, rng) for _ in range(3)]
    stacked = {k: torch.tensor(np.stack([p[k] for p in batch])) for k in batch[0]}
    out = model(**stacked)
    assert out.dtype == dtype and out.shape == (3, model.n_vertices, 3)
    for i, p in enumerate(batch):
        np.testing.assert_allclose(out[i].double().numpy(), reference(model, p), atol=1e-5, rtol=0)


def test_missing_parameters_are_zero_and_rest_pose_is_template(toy_model, tmp_path):
    write_model_file(tmp_path / "m.npz", toy_model)
    model = FlameModel.load(tmp_path / "m.npz", dtype=torch.float64)
    rest = model()
    assert rest.shape == (1, 40, 3)
    np.testing.assert_allclose(rest[0].numpy(), toy_model["v_template"], atol=1e-12)
    moved = model(translation=torch.tensor([[0.0, 1.0, 0.0]]))
    np.testing.assert_allclose((moved - rest)[0].numpy(), np.tile([0.0, 1.0, 0.0], (40, 1)), atol=1e-12)


def test_static_offset_and_fewer_components(toy_model, tmp_path):
    write_model_file(tmp_path / "m.npz", toy_model)
    model = FlameModel.load(tmp_path / "m.npz", dtype=torch.float64)
    rng = np.random.default_rng(3)
    p = random_params(model, rng)
    p["shape"][2:] = 0.0
    offset = rng.normal(scale=0.01, size=(40, 3))
    tensors = {k: torch.tensor(v)[None] for k, v in p.items()}
    tensors["shape"] = tensors["shape"][:, :2]  # only the first two shape components given
    out = model(**tensors, static_offset=torch.tensor(offset)[None])
    np.testing.assert_allclose(out[0].numpy(), reference(model, p, offset), atol=1e-10)


def test_gradients_match_finite_differences(toy_model, tmp_path):
    write_model_file(tmp_path / "m.pkl", toy_model)
    model = FlameModel.load(tmp_path / "m.pkl", dtype=torch.float64)
    rng = np.random.default_rng(11)
    names = list(random_params(model, rng))
    values = [torch.tensor(v, requires_grad=True) for v in random_params(model, rng, batch=2).values()]
    # Include the exact rest pose for one joint: the Rodrigues series branch must differentiate too.
    values[names.index("jaw_pose")].data[0] = 0.0
    offset = torch.tensor(rng.normal(scale=0.01, size=(2, 40, 3)), requires_grad=True)

    def f(*args):
        return model(**dict(zip(names, args[:-1])), static_offset=args[-1])

    assert torch.autograd.gradcheck(f, (*values, offset), eps=1e-6, atol=1e-6)


def test_float32_gradients_near_rest_pose_are_accurate(toy_model, tmp_path):
    write_model_file(tmp_path / "m.npz", toy_model)
    m32 = FlameModel.load(tmp_path / "m.npz", dtype=torch.float32)
    m64 = FlameModel.load(tmp_path / "m.npz", dtype=torch.float64)
    grads = []
    for model, dtype in ((m32, torch.float32), (m64, torch.float64)):
        jaw = torch.tensor([[1e-4, -2e-4, 5e-4]], dtype=dtype, requires_grad=True)
        model(jaw_pose=jaw).square().sum().backward()
        grads.append(jaw.grad.double())
    np.testing.assert_allclose(grads[0].numpy(), grads[1].numpy(), rtol=1e-4, atol=1e-6)


def test_pkl_and_npz_round_trip_and_chumpy_wrapping(procedural_head, tmp_path):
    write_model_file(tmp_path / "a.pkl", procedural_head, chumpy_keys=("shapedirs", "v_template"))
    write_model_file(tmp_path / "a.npz", procedural_head)
    from_pkl = read_model_file(tmp_path / "a.pkl")
    from_npz = read_model_file(tmp_path / "a.npz")
    for field in ("v_template", "faces", "shapedirs", "exprdirs", "posedirs", "J_regressor", "weights", "parents"):
        np.testing.assert_array_equal(getattr(from_pkl, field), getattr(from_npz, field), err_msg=field)
    np.testing.assert_array_equal(from_pkl.v_template, procedural_head["v_template"])
    np.testing.assert_array_equal(from_pkl.J_regressor, procedural_head["J_regressor"])
    np.testing.assert_array_equal(from_pkl.texture, procedural_head["texture"])
    assert from_pkl.expression_names == [str(n) for n in procedural_head["expression_names"]]


def test_our_pkl_reads_with_plain_pickle_and_scipy(procedural_head_pkl, procedural_head):
    """A reader we did not write: the standard unpickler, as FLAME's own loaders use it."""
    import scipy.sparse

    with open(procedural_head_pkl, "rb") as handle:
        loaded = pickle.load(handle, encoding="latin1")
    assert scipy.sparse.issparse(loaded["J_regressor"])
    np.testing.assert_array_equal(loaded["J_regressor"].toarray(), procedural_head["J_regressor"])
    for key in ("v_template", "f", "shapedirs", "posedirs", "weights", "kintree_table"):
        np.testing.assert_array_equal(np.asarray(loaded[key]), procedural_head[key], err_msg=key)


class _Exploit:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


def test_hostile_pickle_is_refused_and_nothing_runs(toy_model, tmp_path):
    marker = tmp_path / "pwned"
    payload = dict(toy_model, shapedirs=_Exploit(marker))
    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps(payload, protocol=2))
    with pytest.raises(UnsafePickleError, match=r"refused to load global '(posix|nt).system'"):
        FlameModel.load(path)
    assert not marker.exists()


def test_hostile_builtins_eval_is_refused(tmp_path):
    path = tmp_path / "evil.pkl"
    path.write_bytes(b"cbuiltins\neval\n(V__import__('os').system('true')\ntR.")
    with pytest.raises(UnsafePickleError, match="builtins.eval"):
        read_model_file(path)


def _bad_model_cases(toy):
    nan_template = toy["v_template"].copy()
    nan_template[3, 1] = np.nan
    yield "missing key", {k: v for k, v in toy.items() if k != "weights"}, "weights", "missing"
    yield "wrong shape", dict(toy, posedirs=toy["posedirs"][:, :, :30]), "posedirs", r"expected shape \(40, 3, 36\)"
    yield "bad face index", dict(toy, f=toy["f"] + 100), "'f'", "vertex indices"
    yield "nan", dict(toy, v_template=nan_template), "v_template", "NaN"
    yield "weights rows", dict(toy, weights=toy["weights"][:, :4]), "weights", "expected shape"
    yield "unknown split", {k: v for k, v in toy.items() if k != "n_shape"}, "shapedirs", "give n_shape"
    yield "string array", dict(toy, v_template=np.array(["a", "b"])), "v_template", "numeric"


@pytest.mark.parametrize("case", range(7))
@pytest.mark.parametrize("suffix", [".pkl", ".npz"])
def test_malformed_model_files_name_file_and_field(tmp_path, case, suffix):
    name, model, field, message = list(_bad_model_cases(make_toy_model()))[case]
    path = tmp_path / f"bad{suffix}"
    if suffix == ".npz":
        np.savez(path, **model)
    else:
        path.write_bytes(pickle.dumps(model, protocol=2))
    with pytest.raises(ModelFileError) as info:
        read_model_file(path)
    assert str(path) in str(info.value), name
    assert field in str(info.value) and re.search(message, str(info.value)), str(info.value)


def test_truncated_and_non_dict_files(toy_model, tmp_path):
    good = tmp_path / "good.pkl"
    write_model_file(good, toy_model)
    truncated = tmp_path / "truncated.pkl"
    truncated.write_bytes(good.read_bytes()[:500])
    with pytest.raises(ModelFileError, match="truncated.pkl: not a readable FLAME pickle"):
        read_model_file(truncated)
    listed = tmp_path / "list.pkl"
    listed.write_bytes(pickle.dumps([1, 2, 3], protocol=2))
    with pytest.raises(ModelFileError, match="expected a pickled dict"):
        read_model_file(listed)
    with pytest.raises(ModelFileError, match="file not found"):
        read_model_file(tmp_path / "nope.pkl")


def test_too_many_components_requested(toy_model, tmp_path):
    write_model_file(tmp_path / "m.npz", toy_model)
    with pytest.raises(ModelFileError, match="asked for 9 expression components, the file has 3"):
        read_model_file(tmp_path / "m.npz", n_expr=9)
    model = FlameModel.load(tmp_path / "m.npz", n_shape=2, n_expr=1)
    assert (model.n_shape, model.n_expr) == (2, 1)


def test_official_400_component_split(tmp_path):
    toy = make_toy_model(n_shape=300, n_expr=100)
    del toy["n_shape"]
    write_model_file(tmp_path / "flame.pkl", toy, chumpy_keys=("shapedirs",))
    model = FlameModel.load(tmp_path / "flame.pkl", n_shape=100, n_expr=50)
    np.testing.assert_array_equal(model.exprdirs.double().numpy(), toy["shapedirs"][:, :, 300:350].astype(np.float32))


def test_bad_parameter_shapes_are_reported(toy_model, tmp_path):
    write_model_file(tmp_path / "m.npz", toy_model)
    model = FlameModel.load(tmp_path / "m.npz")
    with pytest.raises(Exception, match="jaw_pose.*expected shape"):
        model(jaw_pose=torch.zeros(3))
    with pytest.raises(Exception, match="expr.*expected 3 values"):
        model(expr=torch.zeros(1, 5))
    with pytest.raises(Exception, match="unknown FLAME parameter"):
        model(pose=torch.zeros(1, 3))


def test_chumpy_wrapped_arrays_are_written_as_chumpy_globals(toy_model, tmp_path):
    """The official FLAME 2020 files wrap arrays in ``chumpy.ch.Ch``; ours can too."""
    import pickletools

    path = tmp_path / "chumpy.pkl"
    write_model_file(path, toy_model, chumpy_keys=("shapedirs",))
    ops = [(op.name, arg) for op, arg, _ in pickletools.genops(path.read_bytes())]
    assert ("GLOBAL", "chumpy.ch Ch") in ops
    np.testing.assert_array_equal(read_model_file(path).shapedirs, toy_model["shapedirs"][:, :, :4])


def test_numpy_flame_equals_the_torch_model(tmp_path):
    """Blender poses heads with the numpy evaluation (no torch needed there); it is the same FLAME."""
    from mogaface.core.flame.numpy_model import NumpyFlame

    write_model_file(tmp_path / "toy.npz", make_toy_model(n_vertices=30, n_shape=4, n_expr=3, seed=5))
    arrays = read_model_file(tmp_path / "toy.npz")
    torch_model = FlameModel(arrays, dtype=torch.float64)
    numpy_model = NumpyFlame(arrays)
    rng = np.random.default_rng(7)
    for scale in (0.0, 1e-4, 0.4, 1.5):  # the rest pose, the Taylor branch, ordinary and large angles
        params = {"shape": rng.normal(size=4), "expr": rng.normal(size=2),  # fewer expr: padded with zeros
                  "rotation": rng.normal(scale=scale, size=3), "neck_pose": rng.normal(scale=scale, size=3),
                  "jaw_pose": rng.normal(scale=scale, size=3), "eyes_pose": rng.normal(scale=scale, size=6),
                  "translation": rng.normal(size=3), "static_offset": rng.normal(scale=0.01, size=(30, 3))}
        expected = torch_model(**{k: torch.as_tensor(v)[None] for k, v in params.items()})[0].numpy()
        got = numpy_model(**params)
        assert np.abs(got - expected).max() < 1e-10, scale
