"""PLY export and import: world space matches the avatar's render, binding space round-trips."""

import numpy as np
import pytest
import torch
from test_evaluate_fixtures import fake_run, render_np, tiny_capture

from mogaface.core.avatar.avatar import Avatar
from mogaface.core.avatar.export import (
    export_binding_ply,
    export_world_ply,
    flame_param_path,
    import_binding_ply,
    load_flame_param_npz,
    render_world_ply,
)
from mogaface.core.cli import main
from mogaface.core.data.capture import Capture
from mogaface.core.errors import InputError
from mogaface.core.evaluate.protocols import TrackedParams
from mogaface.core.flame.model import FlameModel
from mogaface.core.io.ply import gaussian_property_names
from mogaface.core.run.folder import RunFolder

TIMESTEPS = (0, 6, 13)  # trained, trained, held-out sequence


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    run = RunFolder(fake_run(tmp_path_factory))
    capture = Capture.open(tiny_capture(tmp_path_factory))
    source = TrackedParams(capture, run)
    return run, capture, run.load_avatar(), {t: source.params_for(t) for t in TIMESTEPS}


def test_world_ply_renders_as_the_avatar(setup, tmp_path):
    run, capture, avatar, params = setup
    assert avatar.gaussians.active_sh_degree < avatar.gaussians.max_sh_degree  # unused bands must not leak
    for t in (0, 13):
        path = export_world_ply(avatar, params[t], tmp_path / f"{t}.ply")
        for camera in list(capture.cameras.values())[::2]:
            expected, expected_alpha = render_np(avatar, params[t], camera)
            out = render_world_ply(path, camera)
            assert expected_alpha.max() > 0.5  # something is in view
            np.testing.assert_allclose(out.rgb.numpy(), expected, atol=1e-4)
            np.testing.assert_allclose(out.alpha.numpy(), expected_alpha, atol=1e-4)


def test_world_ply_follows_the_timestep(setup, tmp_path):
    _, _, avatar, params = setup
    a = export_world_ply(avatar, params[0], tmp_path / "a.ply")
    b = export_world_ply(avatar, params[13], tmp_path / "b.ply")
    import trimesh

    xa = trimesh.load(a, process=False).vertices
    xb = trimesh.load(b, process=False).vertices
    assert np.abs(xa - xb).max() > 1e-3


def test_plys_parse_with_trimesh_in_the_3dgs_layout(setup, tmp_path):
    import trimesh

    _, _, avatar, params = setup
    world = export_world_ply(avatar, params[0], tmp_path / "world.ply")
    bound = export_binding_ply(avatar, tmp_path / "bound.ply", params[0])[0]
    n = len(avatar.gaussians)
    for path, binding in ((world, False), (bound, True)):
        cloud = trimesh.load(path, process=False)
        assert len(cloud.vertices) == n
        names = list(cloud.metadata["_ply_raw"]["vertex"]["data"].dtype.names)
        assert names == gaussian_property_names(3, with_binding=binding)
    data = trimesh.load(bound, process=False).metadata["_ply_raw"]["vertex"]["data"]
    np.testing.assert_array_equal(data["binding_0"], avatar.gaussians.binding.numpy())
    np.testing.assert_allclose(data["opacity"], avatar.gaussians.opacity_logit.detach().numpy(), rtol=1e-6)
    np.testing.assert_allclose(data["x"], avatar.gaussians.local_position[:, 0].detach().numpy(), rtol=1e-6)
    world_data = trimesh.load(world, process=False).metadata["_ply_raw"]["vertex"]["data"]
    np.testing.assert_array_equal(world_data["nx"], 0)
    assert np.all(world_data["f_rest_44"] == 0) and np.any(world_data["f_rest_0"] != 0)  # degree 1 active of 3


def test_binding_ply_round_trip_renders_identically(setup, tmp_path):
    run, capture, avatar, params = setup
    ply = tmp_path / "bound.ply"
    written = export_binding_ply(avatar, ply, params[6])
    assert written == [ply, flame_param_path(ply), ply.with_name("flame_param.npz")]
    assert written[1].name == "bound.flame_param.npz"
    stored = load_flame_param_npz(written[1])
    assert set(stored) == set(params[6])
    for key in params[6]:
        np.testing.assert_array_equal(stored[key], params[6][key])
    raw = np.load(written[1])
    assert raw["expr"].shape == (1, len(params[6]["expr"])) and raw["shape"].ndim == 1  # GaussianAvatars' layout
    imported = import_binding_ply(ply, run.root / "head.pkl")
    camera = capture.cameras["cam01"]
    for t in TIMESTEPS:
        before, _ = render_np(avatar, params[t], camera)
        after, _ = render_np(imported, params[t], camera)
        np.testing.assert_allclose(after, before, atol=1e-6)


def test_import_refuses_world_ply_and_foreign_heads(setup, tmp_path, toy_model):
    run, _, avatar, params = setup
    world = export_world_ply(avatar, params[0], tmp_path / "world.ply")
    with pytest.raises(InputError, match="binding_0"):
        import_binding_ply(world, run.root / "head.pkl")
    from mogaface.core.flame.model_file import write_model_file

    toy = tmp_path / "toy.pkl"
    write_model_file(toy, toy_model)
    bound = export_binding_ply(avatar, tmp_path / "bound.ply")[0]
    with pytest.raises(InputError, match="faces"):
        import_binding_ply(bound, toy)


def test_export_and_import_commands(setup, tmp_path, capsys):
    run, capture, avatar, params = setup
    ply = tmp_path / "out" / "t6.ply"
    assert main(["export-ply", str(run.root), "--timestep", "6", "--out", str(ply), "--binding-space"]) == 0
    assert flame_param_path(ply).exists()
    pt = tmp_path / "imported" / "avatar.pt"
    assert main(["import-ply", str(ply), "--head", str(run.root / "head.pkl"), "--out", str(pt)]) == 0
    assert (pt.parent / "head.pkl").exists()
    loaded = Avatar.load(pt)
    camera = capture.cameras["cam00"]
    np.testing.assert_allclose(render_np(loaded, params[6], camera)[0], render_np(avatar, params[6], camera)[0], atol=1e-6)
    world = tmp_path / "world.ply"
    assert main(["export-ply", str(run.root), "--timestep", "13", "--out", str(world)]) == 0
    np.testing.assert_allclose(render_world_ply(world, camera).rgb.numpy(), render_np(avatar, params[13], camera)[0], atol=1e-4)
    assert main(["export-ply", str(run.root), "--timestep", "99", "--out", str(tmp_path / "x.ply")]) == 2
    assert "timestep" in capsys.readouterr().err
    assert not (tmp_path / "x.ply").exists()


# -- heads with teeth, and GaussianAvatars' own point_cloud.ply ----------------------------------
@pytest.fixture(scope="module")
def flame_head(tmp_path_factory):
    """A head model of FLAME's topology (5023 vertices, synthetic bases): the teeth can be added."""
    import vhap_fixture as V

    from mogaface.core.flame.model_file import write_model_file

    path = tmp_path_factory.mktemp("flame_head") / "head.npz"
    write_model_file(path, V.synthetic_flame_topology())
    return path


def test_import_of_an_avatar_bound_to_the_teeth(flame_head, tmp_path):
    """Our own export of a VHAP-tracked avatar (5143 vertices, FLAME's faces and 168 of teeth) comes back on
    the head with teeth."""
    avatar = Avatar.initial(flame_head, 1, n_vertices=5143)
    ply = tmp_path / "teeth.ply"
    export_binding_ply(avatar, ply)
    out = tmp_path / "imported" / "avatar.pt"
    assert main(["import-ply", str(ply), "--head", str(flame_head), "--out", str(out)]) == 0
    loaded = Avatar.load(out)
    assert loaded.flame.n_vertices == 5143 and len(loaded.flame.faces) == len(avatar.flame.faces)
    assert int(loaded.gaussians.binding.max()) == len(avatar.flame.faces) - 1 > FlameModel.load(flame_head).faces.shape[0]
    with torch.no_grad():
        vertices = avatar.flame.v_template
        expected, got = avatar.gaussians.world(vertices, avatar.flame.faces), loaded.gaussians.world(vertices, loaded.flame.faces)
    for key in ("means", "quats", "scales", "opacities"):
        np.testing.assert_allclose(got[key].numpy(), expected[key].numpy(), atol=1e-6)


def gaussianavatars_ply(path, binding, sh_degree=3, seed=0):
    """A ``point_cloud.ply`` as GaussianAvatars' ``save_ply`` writes it (plyfile, every property
    ``'f4'``, ``binding_0`` included): x y z, nx ny nz, f_dc_*, f_rest_*, opacity, scale_*, rot_*."""
    names = gaussian_property_names(sh_degree, with_binding=True)
    rng = np.random.default_rng(seed)
    table = np.zeros(len(binding), dtype=[(n, "f4") for n in names])
    for n in names:
        table[n] = rng.normal(scale=0.3, size=len(binding))
    table["nx"] = table["ny"] = table["nz"] = 0
    table["binding_0"] = binding
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(binding)}"]
    header += [f"property float {n}" for n in names] + ["end_header"]
    path.write_bytes(("\n".join(header) + "\n").encode() + table.tobytes())
    return table


def test_import_of_a_gaussianavatars_point_cloud(flame_head, tmp_path):
    faces = len(FlameModel.load(flame_head, n_vertices=5143).faces)  # 10144 on FLAME itself
    binding = np.r_[np.arange(faces), [faces - 1, 0]].astype(np.float32)
    table = gaussianavatars_ply(tmp_path / "point_cloud.ply", binding)
    avatar = import_binding_ply(tmp_path / "point_cloud.ply", flame_head)
    assert avatar.flame.n_vertices == 5143
    np.testing.assert_array_equal(avatar.gaussians.binding.numpy(), binding.astype(np.int64))
    np.testing.assert_array_equal(avatar.gaussians.local_position[:, 1].detach().numpy(), table["y"])
    np.testing.assert_array_equal(avatar.gaussians.local_rotation[:, 3].detach().numpy(), table["rot_3"])
    np.testing.assert_array_equal(avatar.gaussians.sh_rest[:, 0, 0].detach().numpy(), table["f_rest_0"])
    np.testing.assert_array_equal(avatar.gaussians.sh_rest[:, 0, 1].detach().numpy(), table["f_rest_15"])  # channel-major
    gaussianavatars_ply(tmp_path / "beyond.ply", np.array([0, faces], np.float32))
    with pytest.raises(InputError, match=f"face ids reach {faces}.*with FLAME's teeth"):
        import_binding_ply(tmp_path / "beyond.ply", flame_head)
    gaussianavatars_ply(tmp_path / "half.ply", np.array([0, 2.5], np.float32))
    with pytest.raises(InputError, match="binding_0.*non-negative integers"):
        import_binding_ply(tmp_path / "half.ply", flame_head)
