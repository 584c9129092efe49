"""The reference mesh renderer against analytic expectations."""

import numpy as np
import pytest

from mogaface.core.camera import Camera, intrinsics_matrix
from mogaface.core.data.mesh_render import Lighting, render_mesh

FLAT = Lighting(key=0.0, fill=0.0, ambient=1.0)  # colour == texel
BG = (0.1, 0.2, 0.3)


def _cam(size=64, f=64.0) -> Camera:
    """Camera at the origin looking down +z (OpenCV axes)."""
    return Camera(intrinsics_matrix(f, f, size / 2, size / 2), np.eye(4), size, size)


def _quad(x0, x1, y0, y1, z):
    """Axis-aligned quad facing the camera at the origin; uv (0,0) at (x0, y1) bottom-left."""
    v = np.array([[x0, y1, z], [x1, y1, z], [x1, y0, z], [x0, y0, z]], dtype=float)
    vt = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    f = np.array([[0, 1, 2], [0, 2, 3]])  # normal toward the camera (counter-clockwise seen from it)
    return v, f, vt, f.copy()


def _solid(colour, size=4):
    return np.broadcast_to(np.asarray(colour, np.float32), (size, size, 3)).copy()


def test_quad_position_and_colour():
    v, f, vt, ft = _quad(-0.5, 0.5, -0.5, 0.5, 2.0)  # projects to pixels [16, 48)
    rgb, alpha = render_mesh(v, f, vt, ft, _solid((0.5, 0.25, 1.0)), _cam(), BG, lighting=FLAT)
    assert rgb.shape == (64, 64, 3) and rgb.dtype == np.float32 and alpha.dtype == np.float32
    inside = np.zeros((64, 64), bool)
    inside[16:48, 16:48] = True
    np.testing.assert_allclose(alpha[inside], 1.0)
    np.testing.assert_allclose(alpha[~inside], 0.0)
    np.testing.assert_allclose(rgb[inside], np.broadcast_to([0.5, 0.25, 1.0], (inside.sum(), 3)), atol=1e-6)
    np.testing.assert_allclose(rgb[~inside], np.broadcast_to(BG, ((~inside).sum(), 3)), atol=1e-6)


def test_checker_texture_lands_where_expected():
    # 4x4 checker cells, texture row 0 is the top (v = 1).
    cells = (np.add.outer(np.arange(4), np.arange(4)) % 2).astype(np.float32)
    tex = np.repeat(np.repeat(cells, 16, 0), 16, 1)[..., None].repeat(3, 2)
    v, f, vt, ft = _quad(-0.5, 0.5, -0.5, 0.5, 2.0)
    rgb, _ = render_mesh(v, f, vt, ft, tex, _cam(), BG, lighting=FLAT)
    for ci in range(4):
        for cj in range(4):
            # The quad spans 32 px, so each cell is 8 px; test the cell's centre pixel.
            i, j = 16 + 8 * ci + 4, 16 + 8 * cj + 4
            np.testing.assert_allclose(rgb[i, j], cells[ci, cj], atol=1e-6)


def test_antialiased_edge_has_fractional_alpha():
    # Left edge at u = 16 + 1/3: of the 3x3 samples in column 16, two of three columns are covered.
    x0 = (16 + 1 / 3 - 32) / 64 * 2.0
    v, f, vt, ft = _quad(x0, 0.5, -0.5, 0.5, 2.0)
    rgb, alpha = render_mesh(v, f, vt, ft, _solid((1.0, 1.0, 1.0)), _cam(), BG, lighting=FLAT)
    np.testing.assert_allclose(alpha[20:44, 16], 2 / 3, atol=1e-6)
    np.testing.assert_allclose(rgb[20:44, 16], np.broadcast_to(2 / 3 + np.array(BG) / 3, (24, 3)), atol=1e-6)
    np.testing.assert_allclose(alpha[20:44, 15], 0.0)
    np.testing.assert_allclose(alpha[20:44, 17], 1.0)


def test_perspective_correct_uv_on_tilted_plane():
    # A plane tilted steeply in depth; texture R = u, G = v (linear ramps are exact under bilinear).
    n = 256
    ramp = (np.arange(n) + 0.5) / n
    tex = np.zeros((n, n, 3), np.float32)
    tex[..., 0] = ramp[None, :]
    tex[..., 1] = ramp[::-1, None]
    p0, eu, ev = np.array([-1.0, 0.6, 1.5]), np.array([2.0, 0.0, 0.0]), np.array([0.0, -1.2, 4.0])
    v = np.array([p0, p0 + eu, p0 + eu + ev, p0 + ev])
    vt = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    cam = _cam()
    rgb, alpha = render_mesh(v, f, vt, f, tex, cam, BG, lighting=FLAT, supersample=1)
    # Analytic: intersect each pixel's ray with the plane and read (u, v) off the hit point.
    normal = np.cross(eu, ev)
    jj, ii = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5)
    rays = np.stack([(jj - 32) / 64, (ii - 32) / 64, np.ones_like(jj)], -1)
    hit = rays * ((p0 @ normal) / (rays @ normal))[..., None]
    local = hit - p0
    u = local @ eu / (eu @ eu)
    w = local @ ev / (ev @ ev)
    interior = (u > 0.02) & (u < 0.98) & (w > 0.02) & (w < 0.98)
    assert interior.sum() > 300
    assert (alpha[interior] == 1).all()
    np.testing.assert_allclose(rgb[interior][:, 0], u[interior], atol=2e-3)
    np.testing.assert_allclose(rgb[interior][:, 1], w[interior], atol=2e-3)


def _sphere(n_lat=16, n_lon=24, radius=0.3, centre=(0, 0, 2)):
    lat = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    lon = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    ring = np.stack(np.meshgrid(lat, lon, indexing="ij"), -1).reshape(-1, 2)
    theta, phi = ring[:, 0], ring[:, 1]
    dirs = np.stack([np.sin(theta) * np.cos(phi), np.cos(theta), np.sin(theta) * np.sin(phi)], 1)
    dirs = np.vstack([[0, 1, 0], dirs, [0, -1, 0]])
    import scipy.spatial

    faces = scipy.spatial.ConvexHull(dirs).simplices
    # Orient faces outward.
    tri = dirs[faces]
    outward = np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), tri.mean(1)) > 0
    faces[~outward] = faces[~outward][:, ::-1]
    vt = np.stack([0.5 + 0.5 * dirs[:, 0], 0.5 + 0.5 * dirs[:, 1]], 1)
    return dirs * radius + np.asarray(centre, float), faces, vt


def test_visible_vertices_land_in_mask():
    v, f, vt = _sphere()
    cam = Camera.look_at((0.4, 0.3, 0.5), (0, 0, 2), width=48, height=40, fov_x=0.5)
    rgb, alpha = render_mesh(v, f, vt, f, _solid((0.8, 0.6, 0.5)), cam, BG)
    assert np.isfinite(rgb).all() and 0 <= rgb.min() and rgb.max() <= 1
    uv, depth = cam.project(v)
    outward = (v - np.array([0, 0, 2])) / 0.3
    to_cam = cam.center - v
    cosine = np.einsum("ij,ij->i", outward, to_cam / np.linalg.norm(to_cam, axis=1, keepdims=True))
    assert (depth > 0).all()
    cols, rows = np.floor(uv).astype(int).T
    visible = cosine > 0.2  # clearly visible, not grazing the silhouette
    assert visible.sum() > 20
    assert (alpha[rows[visible], cols[visible]] > 0).all()
    # Every vertex (grazing ones included) lies on or next to the rendered silhouette.
    padded = np.pad(alpha, 1)
    near_mask = np.max([padded[1 + di : 41 + di, 1 + dj : 49 + dj] for di in (-1, 0, 1) for dj in (-1, 0, 1)], 0)
    assert (near_mask[rows, cols] > 0).all()
    assert ((alpha > 0) & (alpha < 1)).any()  # anti-aliased silhouette


def test_nearer_surface_wins_regardless_of_order():
    near = _quad(-0.5, 0.5, -0.5, 0.5, 2.0)
    far = _quad(-1.0, 1.0, -1.0, 1.0, 3.0)
    v = np.vstack([far[0], near[0]])
    f = np.vstack([far[1], near[1] + 4])
    vt = np.vstack([far[2], near[2]])
    tex = np.zeros((2, 2, 3), np.float32)
    tex[:, 0] = [1, 0, 0]  # u < 0.5: red
    tex[:, 1] = [0, 0, 1]  # u > 0.5: blue
    vt_far = np.full_like(far[2], 0.1)
    vt_near = np.full_like(near[2], 0.9)
    vt = np.vstack([vt_far, vt_near])
    for order in (slice(None), slice(None, None, -1)):
        rgb, _ = render_mesh(v, f[order], vt, f[order], tex, _cam(), BG, lighting=FLAT)
        np.testing.assert_allclose(rgb[32, 32], [0, 0, 1], atol=1e-6)
        np.testing.assert_allclose(rgb[12, 32], [1, 0, 0], atol=1e-6)


def test_back_faces_drawn_with_facing_normal_or_culled():
    v, f, vt, ft = _quad(-0.5, 0.5, -0.5, 0.5, 2.0)
    head_on = Lighting(key_dir=(0, 0, -1), key=0.5, fill=0.0, ambient=0.5, space="camera")
    front, a_front = render_mesh(v, f, vt, ft, _solid((1, 1, 1)), _cam(), BG, lighting=head_on)
    back, a_back = render_mesh(v, f[:, ::-1], vt, ft[:, ::-1], _solid((1, 1, 1)), _cam(), BG, lighting=head_on)
    np.testing.assert_allclose(front, back, atol=1e-6)
    np.testing.assert_allclose(front[32, 32], 1.0, atol=1e-6)
    np.testing.assert_allclose(a_front, a_back)
    _, culled = render_mesh(v, f[:, ::-1], vt, ft[:, ::-1], _solid((1, 1, 1)), _cam(), BG, cull_backfaces=True)
    assert culled.max() == 0
    _, kept = render_mesh(v, f, vt, ft, _solid((1, 1, 1)), _cam(), BG, cull_backfaces=True)
    assert kept.max() == 1


@pytest.mark.parametrize("shift", [(5.0, 0.0, 0.0), (0.0, 0.0, -4.0)], ids=["off-screen", "behind"])
def test_invisible_mesh_gives_empty_image(shift):
    v, f, vt = _sphere()
    v = v + np.array(shift)
    rgb, alpha = render_mesh(v, f, vt, f, _solid((1, 0, 0)), _cam(), BG)
    assert alpha.max() == 0
    np.testing.assert_allclose(rgb, np.broadcast_to(BG, rgb.shape), atol=1e-6)


def test_mesh_through_near_plane_is_clipped_without_nan():
    v, f, vt = _sphere(centre=(0, 0, 0.1), radius=0.5)  # the camera sits inside the sphere
    rgb, alpha = render_mesh(v, f, vt, f, _solid((0.3, 0.6, 0.9)), _cam(), BG, near=0.05)
    assert np.isfinite(rgb).all() and np.isfinite(alpha).all()
    assert alpha.min() == 1.0  # seen from inside, the sphere fills the view


def test_empty_and_bad_inputs():
    cam = _cam(8)
    none = np.zeros((0, 3), int)
    rgb, alpha = render_mesh(np.zeros((0, 3)), none, np.zeros((0, 2)), none, _solid((1, 1, 1)), cam, BG)
    assert rgb.shape == (8, 8, 3) and alpha.max() == 0
    v, f, vt, ft = _quad(-0.5, 0.5, -0.5, 0.5, 2.0)
    from mogaface.core.errors import InputError

    with pytest.raises(InputError):
        render_mesh(np.full_like(v, np.nan), f, vt, ft, _solid((1, 1, 1)), cam)
    with pytest.raises(InputError):
        render_mesh(v, f + 10, vt, ft, _solid((1, 1, 1)), cam)


def test_precomputed_normals_give_the_same_image():
    from mogaface.core.data.mesh_render import vertex_normals

    v, f, vt = _sphere()
    cam = Camera.look_at((0.2, 0.3, 0.8), (0, 0, 2), width=32, height=32, fov_x=0.6)
    tex = _solid((0.7, 0.5, 0.4))
    plain = render_mesh(v, f, vt, f, tex, cam)
    given = render_mesh(v, f, vt, f, tex, cam, normals=vertex_normals(v, f))
    np.testing.assert_array_equal(plain[0], given[0])
    key_only = dict(fill=0.0, ambient=0.0)
    from_minus_x = render_mesh(v, f, vt, f, tex, cam, (0, 0, 0), lighting=Lighting(key_dir=(-1, 0, 0), **key_only))[0]
    from_plus_x = render_mesh(v, f, vt, f, tex, cam, (0, 0, 0), lighting=Lighting(key_dir=(1, 0, 0), **key_only))[0]
    # World-space light: the sphere's -x side is bright; this camera looks along +z, so world -x
    # is on the image's right (checked by projection).
    side = cam.project([[-0.3, 0.0, 2.0]])[0][0, 0]
    assert side > 16
    assert from_minus_x[:, 18:].mean() > 4 * from_minus_x[:, :14].mean()
    assert from_plus_x[:, :14].mean() > 4 * from_plus_x[:, 18:].mean()
