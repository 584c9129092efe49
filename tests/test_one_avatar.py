"""One avatar everywhere: every consumer of a run trained with MoGaFace modules draws what ``render`` draws.

A tiny run is trained with the full method, then its texture attention is made to move the
Gaussians visibly (so a consumer that dropped the modules would fail by far). The same camera and
timestep are then drawn through each path and compared with the core render:

- ``render`` (the command) and Blender's request path (``core.for_blender.render``): the same code, exact;
- ``export-ply`` world space, read by trimesh and drawn by an independent 3DGS renderer written
  here from the 3DGS reference (EWA splatting, 0.3 px low-pass, front-to-back alpha, alpha cut
  1/255, transmittance stop 1e-4): ≥ 40 dB;
- ``export-ply --binding-space`` posed by GaussianAvatars' own composition, written here from its
  public code (``compute_face_orientation``, roma's ``quat_product(face_orien_quat, rotation)``,
  ``bmm(face_orien_mat, xyz) * face_scaling + face_center``, ``exp(scaling) * face_scaling``) with
  the mesh of ``flame_param.npz`` row ``t``: rotations within 0.1°, ≥ 40 dB;
- ``import-ply`` of that file, then the core render: exact;
- ``core.for_blender.points`` (Gaussians to Mesh): the world Gaussians, exact.
"""

import math

import numpy as np
import pytest
import torch

from mogaface.core.avatar.avatar import Avatar, flame_params_to_torch, render_frame
from mogaface.core.cli import main
from mogaface.core.correction.avatar import ModulatedAvatar
from mogaface.core.evaluate.protocols import TrackedParams
from mogaface.core.for_blender.avatar import avatar_location, load_avatar
from mogaface.core.for_blender.axes import blender_to_flame
from mogaface.core.run.folder import RunFolder

TIMESTEP = 3  # a trained timestep (its corrected parameters come from the run)
HELD_OUT = 13  # a timestep of the held-out sequence (tracked parameters)


@pytest.fixture(scope="module")
def modulated(tmp_path_factory):
    """A run with MoGaFace modules whose texture offsets change the picture (≈ 20 dB from the plain avatar)."""
    from test_mogaface_train import config

    from mogaface.core.correction.model import MoGaFace
    from mogaface.core.data.generator import CaptureSettings, make_capture
    from mogaface.core.train.trainer import Trainer

    root = tmp_path_factory.mktemp("one_avatar")
    make_capture(root / "cap", CaptureSettings(views=3, timesteps=16, size=48, supersample=1), progress=False)
    Trainer(root / "cap", root / "run", config(steps=6)).run()
    run = RunFolder(root / "run")
    model = MoGaFace.load(run.modules_path)
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for head in model.texture.heads.values():
            head.weight.copy_(1.5 * torch.randn(head.weight.shape, generator=generator))
    model.save(run.modules_path)
    avatar = run.load_avatar()
    capture = run.open_capture()
    source = TrackedParams(capture, run)
    camera = capture.cameras[sorted(capture.cameras)[0]]
    return {"run": run, "avatar": avatar, "capture": capture, "source": source, "camera": camera,
            "params": {t: source.params_for(t) for t in (TIMESTEP, HELD_OUT)}}


def psnr(a, b) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(1.0 / mse)


def core_render(m, timestep, avatar=None):
    return render_frame(avatar or m["avatar"], m["params"][timestep], m["camera"], m["run"].background)[0]


# -- an independent 3DGS renderer (3DGS reference: forward.cu / backward.cu semantics) ----------------
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)


def sh_to_color(sh, dirs):
    """3DGS ``computeColorFromSH``: ``sh (N,K,3)``, unit view directions ``(N,3)`` → RGB, clamped at 0."""
    x, y, z = dirs[:, 0:1], dirs[:, 1:2], dirs[:, 2:3]
    k = sh.shape[1]
    out = SH_C0 * sh[:, 0]
    if k > 1:
        out = out - SH_C1 * y * sh[:, 1] + SH_C1 * z * sh[:, 2] - SH_C1 * x * sh[:, 3]
    if k > 4:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out = (out + SH_C2[0] * xy * sh[:, 4] + SH_C2[1] * yz * sh[:, 5] + SH_C2[2] * (2 * zz - xx - yy) * sh[:, 6]
               + SH_C2[3] * xz * sh[:, 7] + SH_C2[4] * (xx - yy) * sh[:, 8])
        if k > 9:
            out = (out + SH_C3[0] * y * (3 * xx - yy) * sh[:, 9] + SH_C3[1] * xy * z * sh[:, 10]
                   + SH_C3[2] * y * (4 * zz - xx - yy) * sh[:, 11] + SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[:, 12]
                   + SH_C3[4] * x * (4 * zz - xx - yy) * sh[:, 13] + SH_C3[5] * z * (xx - yy) * sh[:, 14]
                   + SH_C3[6] * x * (xx - 3 * yy) * sh[:, 15])
    return np.maximum(out + 0.5, 0.0)


def quat_to_matrix(q):
    """Unit-normalised wxyz quaternions → rotation matrices (3DGS ``computeCov3D``)."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    r, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - r * z), 2 * (x * z + r * y),
                     2 * (x * y + r * z), 1 - 2 * (x * x + z * z), 2 * (y * z - r * x),
                     2 * (x * z - r * y), 2 * (y * z + r * x), 1 - 2 * (x * x + y * y)], 1).reshape(-1, 3, 3)


def splat(g, camera, background, band=8):
    """Draw activated Gaussians (``means, quats, scales, opacities, sh``) as the 3DGS reference does,
    in float64, pixel centres at ``j + 0.5`` of OpenCV pixel coordinates."""
    W, H = camera.width, camera.height
    fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]
    R, T = camera.w2c[:3, :3], camera.w2c[:3, 3]
    t = g["means"] @ R.T + T
    keep = t[:, 2] > 0.2  # 3DGS' near plane
    t, idx = t[keep], np.nonzero(keep)[0]
    z = t[:, 2]
    limx, limy = 1.3 * 0.5 * W / fx, 1.3 * 0.5 * H / fy
    tx, ty = np.clip(t[:, 0] / z, -limx, limx) * z, np.clip(t[:, 1] / z, -limy, limy) * z
    J = np.zeros((len(z), 2, 3))
    J[:, 0, 0], J[:, 0, 2] = fx / z, -fx * tx / (z * z)
    J[:, 1, 1], J[:, 1, 2] = fy / z, -fy * ty / (z * z)
    M = quat_to_matrix(g["quats"][idx]) * g["scales"][idx][:, None, :]
    A = J @ R
    cov = A @ (M @ M.transpose(0, 2, 1)) @ A.transpose(0, 2, 1)
    a, b, c = cov[:, 0, 0] + 0.3, cov[:, 0, 1], cov[:, 1, 1] + 0.3
    det = a * c - b * b
    ok = det > 0
    conic = np.stack([c, -b, a], 1) / np.where(ok, det, 1.0)[:, None]
    mid = 0.5 * (a + c)
    radius = np.ceil(3.0 * np.sqrt(mid + np.sqrt(np.maximum(0.1, mid * mid - det))))
    centre = np.stack([fx * t[:, 0] / z + cx, fy * t[:, 1] / z + cy], 1)
    campos = -R.T @ T
    dirs = g["means"][idx] - campos
    color = sh_to_color(g["sh"][idx], dirs / np.linalg.norm(dirs, axis=1, keepdims=True))
    order = np.argsort(z, kind="stable")
    order = order[ok[order]]
    centre, conic, radius, color = centre[order], conic[order], radius[order], color[order]
    opacity = g["opacities"][idx][order]
    out = np.empty((H, W, 3))
    for r0 in range(0, H, band):
        ys, xs = np.meshgrid(np.arange(r0, min(r0 + band, H)) + 0.5, np.arange(W) + 0.5, indexing="ij")
        px, py = xs.reshape(-1, 1), ys.reshape(-1, 1)
        dx, dy = centre[None, :, 0] - px, centre[None, :, 1] - py
        power = -0.5 * (conic[:, 0] * dx * dx + conic[:, 2] * dy * dy) - conic[:, 1] * dx * dy
        alpha = np.minimum(0.99, opacity * np.exp(np.minimum(power, 0.0)))
        used = (power <= 0) & (alpha >= 1.0 / 255.0) & (np.abs(dx) <= radius + 0.5) & (np.abs(dy) <= radius + 0.5)
        alpha = np.where(used, alpha, 0.0)
        alpha = np.where(np.cumprod(1 - alpha, axis=1) >= 1e-4, alpha, 0.0)  # stop before T falls under 1e-4
        transmit = np.cumprod(np.concatenate([np.ones((len(px), 1)), 1 - alpha[:, :-1]], 1), axis=1)
        rgb = (alpha * transmit) @ color + np.prod(1 - alpha, axis=1, keepdims=True) * np.asarray(background)
        out[r0:r0 + band] = rgb.reshape(-1, W, 3)
    return np.clip(out, 0.0, 1.0)


def read_ply_columns(path):
    """A PLY's vertex table as trimesh reads it (not our reader)."""
    import trimesh

    return trimesh.load(path, process=False).metadata["_ply_raw"]["vertex"]["data"]


def ply_sh(table):
    rest = sorted((n for n in table.dtype.names if n.startswith("f_rest_")), key=lambda n: int(n.split("_")[-1]))
    dc = np.stack([table[f"f_dc_{i}"] for i in range(3)], 1)[:, None]
    k = len(rest) // 3
    rest = np.stack([table[n] for n in rest], 1).reshape(len(table), 3, k).transpose(0, 2, 1)
    return np.concatenate([dc, rest], 1).astype(np.float64)


def world_ply_gaussians(path):
    t = read_ply_columns(path)
    col = lambda *names: np.stack([t[n] for n in names], 1).astype(np.float64)  # noqa: E731
    return {"means": col("x", "y", "z"), "quats": col("rot_0", "rot_1", "rot_2", "rot_3"),
            "scales": np.exp(col("scale_0", "scale_1", "scale_2")),
            "opacities": 1 / (1 + np.exp(-t["opacity"].astype(np.float64))), "sh": ply_sh(t)}


# -- GaussianAvatars' composition (scene/gaussian_model.py, utils/graphics_utils.py, roma) ----------
def ga_face_orientation(verts, faces):
    """``compute_face_orientation(verts, faces, return_scale=True)``."""
    def length(x):
        return np.sqrt(np.maximum((x * x).sum(-1, keepdims=True), 1e-20))

    v0, v1, v2 = (verts[faces[:, i]] for i in range(3))
    a0 = (v1 - v0) / length(v1 - v0)
    a1 = np.cross(a0, v2 - v0)
    a1 = a1 / length(a1)
    a2 = np.cross(a1, a0)
    a2 = -a2 / length(a2)
    s = 0.5 * (length(v1 - v0) + np.abs((a2 * (v2 - v0)).sum(-1, keepdims=True)))
    return np.stack([a0, a1, a2], -1), s


def rotmat_to_quat_xyzw(m):
    """A unit quaternion (xyzw, roma's order) of each rotation matrix (either sign: a rotation)."""
    w = np.sqrt(np.maximum(0.0, 1 + m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2])) / 2
    x = np.sqrt(np.maximum(0.0, 1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2])) / 2
    y = np.sqrt(np.maximum(0.0, 1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2])) / 2
    z = np.sqrt(np.maximum(0.0, 1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2])) / 2
    x = np.copysign(x, m[:, 2, 1] - m[:, 1, 2])
    y = np.copysign(y, m[:, 0, 2] - m[:, 2, 0])
    z = np.copysign(z, m[:, 1, 0] - m[:, 0, 1])
    return np.stack([x, y, z, w], 1)


def roma_quat_product(p, q):
    """roma ``quat_product(p, q)`` (xyzw): the Hamilton product ``p q``."""
    vector = p[:, None, 3] * q[:, :3] + q[:, None, 3] * p[:, :3] + np.cross(p[:, :3], q[:, :3])
    return np.concatenate([vector, (p[:, 3] * q[:, 3] - (p[:, :3] * q[:, :3]).sum(1))[:, None]], 1)


def ga_posed(table, verts, faces):
    """GaussianAvatars' ``get_xyz``, ``get_rotation``, ``get_scaling``, ``get_opacity`` of a bound PLY."""
    col = lambda *names: np.stack([table[n] for n in names], 1).astype(np.float64)  # noqa: E731
    binding = np.asarray(table["binding_0"]).astype(np.int64)
    orien, scaling = ga_face_orientation(verts, faces)
    center = verts[faces].mean(1)
    xyz = (orien[binding] @ col("x", "y", "z")[..., None])[..., 0] * scaling[binding] + center[binding]
    rot = col("rot_0", "rot_1", "rot_2", "rot_3")
    rot = rot / np.linalg.norm(rot, axis=1, keepdims=True)
    face_q = rotmat_to_quat_xyzw(orien)[binding]
    world = roma_quat_product(face_q, np.concatenate([rot[:, 1:], rot[:, :1]], 1))  # wxyz → xyzw
    return {"means": xyz, "quats": np.concatenate([world[:, 3:], world[:, :3]], 1),
            "scales": np.exp(col("scale_0", "scale_1", "scale_2")) * scaling[binding],
            "opacities": 1 / (1 + np.exp(-table["opacity"].astype(np.float64))), "sh": ply_sh(table)}


def rotation_error_degrees(a, b):
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.degrees(2 * np.arccos(np.clip(np.abs((a * b).sum(1)), 0.0, 1.0)))


def our_world(m, timestep):
    with torch.no_grad():
        world = m["avatar"].world_gaussians(flame_params_to_torch(m["params"][timestep]))
    return {k: v.double().numpy() for k, v in world.items()}


# -- the tests ------------------------------------------------------------------------------------------
def test_the_run_loads_with_its_modules_and_they_change_the_picture(modulated):
    m = modulated
    assert isinstance(m["avatar"], ModulatedAvatar)
    assert isinstance(load_avatar(m["run"].root), ModulatedAvatar)
    plain = core_render(m, TIMESTEP, Avatar.load(m["run"].avatar_path))
    assert psnr(plain, core_render(m, TIMESTEP)) < 30  # a consumer without the modules would fail below


def test_the_independent_renderer_agrees_with_the_engine(modulated):
    m = modulated
    for t in (TIMESTEP, HELD_OUT):
        world = our_world(m, t)
        world["sh"] = world.pop("colors")
        assert psnr(splat(world, m["camera"], m["run"].background), core_render(m, t)) >= 40


def test_render_command_draws_the_core_render(modulated, tmp_path):
    from mogaface.core.io.image import read_image

    m = modulated
    assert main(["render", str(m["run"].root), "--timesteps", str(TIMESTEP), "--camera", m["camera"].camera_id,
                 "--out", str(tmp_path)]) == 0
    image = read_image(tmp_path / f"{TIMESTEP:05d}_{m['camera'].camera_id}.png")[..., :3]
    np.testing.assert_allclose(image, core_render(m, TIMESTEP), atol=0.5 / 255 + 1e-6)


def test_world_ply_draws_as_render_in_an_independent_renderer(modulated, tmp_path):
    m = modulated
    for t in (TIMESTEP, HELD_OUT):
        ply = tmp_path / f"world_{t}.ply"
        assert main(["export-ply", str(m["run"].root), "--timestep", str(t), "--out", str(ply)]) == 0
        assert psnr(splat(world_ply_gaussians(ply), m["camera"], m["run"].background), core_render(m, t)) >= 40


def test_binding_ply_poses_through_gaussianavatars_composition(modulated, tmp_path):
    m = modulated
    ply = tmp_path / "point_cloud.ply"
    assert main(["export-ply", str(m["run"].root), "--timestep", str(TIMESTEP), "--out", str(ply),
                 "--binding-space"]) == 0
    motion = np.load(tmp_path / "flame_param.npz")  # GaussianAvatars: Path(ply).parent / "flame_param.npz"
    flame = m["avatar"].flame
    row = {k: motion[k][TIMESTEP] for k in ("expr", "rotation", "neck_pose", "jaw_pose", "eyes_pose", "translation")}
    row["expr"] = row["expr"][: flame.n_expr]
    row["shape"] = motion["shape"][: flame.n_shape]
    row["static_offset"] = motion["static_offset"][0, : flame.n_vertices]
    with torch.no_grad():
        verts = flame(**flame_params_to_torch(row))[0].double().numpy()
    posed = ga_posed(read_ply_columns(ply), verts, flame.faces.numpy())
    ours = our_world(m, TIMESTEP)
    angles = rotation_error_degrees(posed["quats"], ours["quats"])
    assert np.median(angles) <= 0.1 and angles.max() <= 0.1
    np.testing.assert_allclose(posed["means"], ours["means"], atol=1e-5)
    np.testing.assert_allclose(posed["scales"], ours["scales"], rtol=1e-4, atol=1e-8)
    np.testing.assert_allclose(posed["opacities"], ours["opacities"], atol=1e-5)
    assert psnr(splat(posed, m["camera"], m["run"].background), core_render(m, TIMESTEP)) >= 40


def test_motion_file_has_one_row_per_timestep_of_the_capture(modulated, tmp_path):
    m = modulated
    ply = tmp_path / "point_cloud.ply"
    assert main(["export-ply", str(m["run"].root), "--timestep", str(TIMESTEP), "--out", str(ply),
                 "--binding-space"]) == 0
    motion = np.load(tmp_path / "flame_param.npz")
    timesteps = m["capture"].timesteps
    assert motion["expr"].shape[0] == max(timesteps) + 1 and set(m["run"].trained_timesteps) < set(timesteps)
    for t in timesteps:
        expected = m["run"].flame_params(t) if t in m["run"].trained_timesteps else m["capture"].flame_params(t)
        n = len(expected["expr"])
        np.testing.assert_allclose(motion["expr"][t, :n], expected["expr"], atol=1e-6)
        np.testing.assert_allclose(motion["jaw_pose"][t], expected["jaw_pose"], atol=1e-6)
        np.testing.assert_allclose(motion["translation"][t], expected["translation"], atol=1e-6)


def test_import_ply_then_render_is_exact(modulated, tmp_path):
    m = modulated
    ply = tmp_path / "bound.ply"
    assert main(["export-ply", str(m["run"].root), "--timestep", str(TIMESTEP), "--out", str(ply),
                 "--binding-space"]) == 0
    out = tmp_path / "imported" / "avatar.pt"
    head = m["run"].head_path()
    assert main(["import-ply", str(ply), "--head", str(head), "--out", str(out)]) == 0
    imported = load_avatar(out)
    assert not isinstance(imported, ModulatedAvatar)  # the exported timestep's offsets are in the file
    np.testing.assert_allclose(core_render(m, TIMESTEP, imported), core_render(m, TIMESTEP), atol=1e-5)


def test_blender_request_and_points_show_the_same_avatar(modulated):
    from mogaface.core.for_blender.points import gaussian_points
    from mogaface.core.for_blender.render import RenderRequest, render

    m = modulated
    avatar_path = str(m["run"].avatar_path)
    params = m["params"][TIMESTEP]
    result = render(RenderRequest(avatar_path, params, m["camera"], m["run"].background))
    np.testing.assert_allclose(result.rgb, core_render(m, TIMESTEP), atol=1e-6)
    points = gaussian_points(avatar_path, params)
    ours = our_world(m, TIMESTEP)
    np.testing.assert_allclose(blender_to_flame(points["position"]), ours["means"], atol=1e-6)
    np.testing.assert_allclose(points["scale"], ours["scales"], rtol=1e-6)
    np.testing.assert_allclose(points["opacity"], ours["opacities"], atol=1e-6)


def test_blender_reads_run_json_as_every_consumer_does(modulated, tmp_path):
    """Blender's avatar field (a run folder or an avatar file) goes through the same checked run.json."""
    import json
    import shutil

    from mogaface.core.errors import InputError

    m = modulated
    path, background = avatar_location(m["run"].root)
    assert path == m["run"].avatar_path.resolve() and background == m["run"].background
    copy = tmp_path / "run"
    copy.mkdir()
    for name in ("avatar.pt", "head.pkl"):
        shutil.copy(m["run"].root / name, copy / name)
    assert avatar_location(copy / "avatar.pt")[1] == (1.0, 1.0, 1.0)  # no run.json: white
    assert not isinstance(load_avatar(copy), ModulatedAvatar)  # no mogaface.pt: the plain avatar
    (copy / "run.json").write_text(json.dumps({"background": [0, 0, 2]}))
    with pytest.raises(InputError, match="run.json.*background"):
        avatar_location(copy)
    with pytest.raises(InputError, match="avatar file not found"):
        load_avatar(copy / "missing.pt")
