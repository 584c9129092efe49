"""Gaussian PLY files: exact header, round trip, and a reader we did not write (trimesh)."""

import numpy as np
import pytest
import trimesh

from mogaface.core.errors import InputError
from mogaface.core.io.ply import gaussian_property_names, read_gaussian_ply, write_gaussian_ply


def gaussians(count=7, degree=3, seed=0, bound=False):
    rng = np.random.default_rng(seed)
    quats = rng.normal(size=(count, 4))
    return {
        "means": rng.normal(size=(count, 3)),
        "scales_log": rng.normal(-4, 1, size=(count, 3)),
        "quats": quats / np.linalg.norm(quats, axis=1, keepdims=True),
        "opacity_logit": rng.normal(size=count),
        "sh": rng.normal(size=(count, (degree + 1) ** 2, 3)),
        "binding": rng.integers(0, 10144, size=count) if bound else None,
    }


def header_of(path):
    data = path.read_bytes()
    return data[: data.index(b"end_header\n") + len(b"end_header\n")].decode("ascii")


def expected_header(count, degree, bound):
    rest = 3 * ((degree + 1) ** 2 - 1)
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    lines += [f"property float {n}" for n in names] + (["property int binding_0"] if bound else [])
    return "\n".join(lines + ["end_header"]) + "\n"


@pytest.mark.parametrize("degree,bound", [(3, False), (0, False), (1, True), (3, True)])
def test_header_lists_the_3dgs_properties_in_order(tmp_path, degree, bound):
    path = tmp_path / "point_cloud.ply"
    write_gaussian_ply(path, **gaussians(5, degree, bound=bound))
    assert header_of(path) == expected_header(5, degree, bound)
    assert len(path.read_bytes()) == len(header_of(path)) + 5 * 4 * len(gaussian_property_names(degree, bound))
    assert not list(tmp_path.glob(".*partial*"))  # the temporary file was renamed, not left behind


@pytest.mark.parametrize("degree,bound", [(3, True), (2, False), (0, True)])
def test_round_trip(tmp_path, degree, bound):
    source = gaussians(9, degree, seed=degree, bound=bound)
    write_gaussian_ply(tmp_path / "g.ply", **source)
    back = read_gaussian_ply(tmp_path / "g.ply")
    assert back["sh_degree"] == degree
    for name in ("means", "scales_log", "quats", "opacity_logit", "sh"):
        assert back[name].dtype == np.float32
        np.testing.assert_array_equal(back[name], np.asarray(source[name], np.float32), err_msg=name)
    if bound:
        np.testing.assert_array_equal(back["binding"], source["binding"])
    else:
        assert back["binding"] is None


def test_torch_tensors_are_accepted(tmp_path):
    import torch

    source = gaussians(5, 1, seed=2, bound=True)
    as_torch = {k: torch.tensor(v, requires_grad=k != "binding") for k, v in source.items()}
    write_gaussian_ply(tmp_path / "t.ply", **as_torch)
    write_gaussian_ply(tmp_path / "n.ply", **source)
    assert (tmp_path / "t.ply").read_bytes() == (tmp_path / "n.ply").read_bytes()


def test_a_reader_we_did_not_write_sees_the_same_values(tmp_path):
    source = gaussians(11, 3, seed=4, bound=True)
    write_gaussian_ply(tmp_path / "g.ply", **source)
    cloud = trimesh.load(tmp_path / "g.ply")
    table = cloud.metadata["_ply_raw"]["vertex"]["data"]
    assert list(table.dtype.names) == gaussian_property_names(3, with_binding=True)
    np.testing.assert_array_equal(cloud.vertices, source["means"].astype(np.float32))
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    sh = source["sh"]
    for c in range(3):
        np.testing.assert_array_equal(table[f"f_dc_{c}"], f32(sh[:, 0, c]))
        for k in range(1, 16):  # channel-major: all of R's 15 coefficients, then G's, then B's
            np.testing.assert_array_equal(table[f"f_rest_{c * 15 + k - 1}"], f32(sh[:, k, c]))
    for i in range(4):
        np.testing.assert_array_equal(table[f"rot_{i}"], f32(source["quats"][:, i]))  # rot_0 is w
    for i in range(3):
        np.testing.assert_array_equal(table[f"scale_{i}"], f32(source["scales_log"][:, i]))
        np.testing.assert_array_equal(table["n" + "xyz"[i]], 0)
    np.testing.assert_array_equal(table["opacity"], f32(source["opacity_logit"]))
    assert table["binding_0"].dtype == np.int32
    np.testing.assert_array_equal(table["binding_0"], source["binding"])


def test_we_read_files_in_the_layout_others_write(tmp_path):
    """Float ``binding_0`` (as GaussianAvatars writes it), doubles, an extra property, a second element."""
    count, names = 4, gaussian_property_names(1) + ["binding_0", "extra"]
    rng = np.random.default_rng(1)
    table = np.zeros(count, dtype=[(n, "<f8" if n == "x" else "<f4") for n in names])
    for n in names:
        table[n] = rng.normal(size=count)
    table["binding_0"] = [3, 1, 4, 1]
    header = ["ply", "format binary_little_endian 1.0", "comment written elsewhere", f"element vertex {count}"]
    header += [f"property {'double' if n == 'x' else 'float'} {n}" for n in names]
    header += ["element face 1", "property list uchar int vertex_indices", "end_header"]
    face = np.array([3], "u1").tobytes() + np.array([0, 1, 2], "<i4").tobytes()
    (tmp_path / "other.ply").write_bytes(("\n".join(header) + "\n").encode() + table.tobytes() + face)
    back = read_gaussian_ply(tmp_path / "other.ply")
    np.testing.assert_array_equal(back["binding"], [3, 1, 4, 1])
    np.testing.assert_array_equal(back["means"][:, 0], table["x"].astype(np.float32))
    np.testing.assert_array_equal(back["sh"][:, 2, 1], table["f_rest_4"])  # G's second rest coefficient


@pytest.mark.parametrize("bad", [2.5, -1.0, float("nan"), 3e9])
def test_float_face_ids_that_are_not_whole_numbers_are_refused(tmp_path, bad):
    count, names = 3, gaussian_property_names(0) + ["binding_0"]
    table = np.zeros(count, dtype=[(n, "<f4") for n in names])
    table["binding_0"] = [0, bad, 2]
    write_binary(tmp_path / "bad.ply", count, names, table.tobytes())
    with pytest.raises(InputError, match="binding_0.*non-negative integers; Gaussian 1 holds"):
        read_gaussian_ply(tmp_path / "bad.ply")


def write_raw(path, header_lines, payload=b""):
    path.write_bytes(("\n".join(header_lines) + "\n").encode() + payload)
    return path


def write_binary(path, count, names, payload=b"", extra=()):
    """A binary PLY of ``count`` vertices declaring the float properties ``names``, then the lines ``extra``."""
    return write_raw(path, ["ply", "format binary_little_endian 1.0", f"element vertex {count}",
                            *[f"property float {n}" for n in names], *extra, "end_header"], payload)


def test_bad_files_name_the_file_and_the_property(tmp_path):
    names = [n for n in gaussian_property_names(0) if n != "opacity"]
    path = write_binary(tmp_path / "no_opacity.ply", 1, names, bytes(4 * len(names)))
    with pytest.raises(InputError, match=r"no_opacity.ply: field 'opacity': missing property"):
        read_gaussian_ply(path)
    ascii_file = write_raw(tmp_path / "ascii.ply", ["ply", "format ascii 1.0", "element vertex 0", "end_header"])
    with pytest.raises(InputError, match=r"ascii.ply: field 'format': expected binary_little_endian"):
        read_gaussian_ply(ascii_file)
    full = gaussian_property_names(0)
    short = write_binary(tmp_path / "short.ply", 2, full, bytes(4 * len(full)))
    with pytest.raises(InputError, match=r"short.ply: field 'vertex': file ends after"):
        read_gaussian_ply(short)
    odd = write_binary(tmp_path / "odd.ply", 0, full, extra=["property float f_rest_0"])
    with pytest.raises(InputError, match=r"odd.ply: field 'f_rest'"):
        read_gaussian_ply(odd)
    (tmp_path / "mesh.obj").write_text("v 0 0 0\n")
    with pytest.raises(InputError, match="mesh.obj: not a PLY file"):
        read_gaussian_ply(tmp_path / "mesh.obj")
    with pytest.raises(InputError, match="missing.ply: file not found"):
        read_gaussian_ply(tmp_path / "missing.ply")


def test_bad_arrays_are_refused_and_nothing_is_written(tmp_path):
    path = tmp_path / "g.ply"
    good = gaussians(3, 1, bound=True)
    for field, value, message in [
        ("sh", np.zeros((3, 3, 3)), r"field 'sh': expected shape \(N, \(d\+1\)\^2, 3\)"),
        ("quats", np.zeros((3, 3)), r"field 'quats': expected shape \(N, 4\)"),
        ("means", np.zeros((2, 3)), r"field 'means': has 2 rows, expected 3"),
        ("opacity_logit", np.array([0.0, np.nan, 0.0]), "field 'opacity_logit': contains NaN"),
        ("binding", np.array([0.5, 1, 2]), "field 'binding': expected \\(3,\\) integer face ids"),
        ("binding", np.array([0, -1, 2]), "field 'binding': face ids must lie in"),
    ]:
        with pytest.raises(InputError, match=message):
            write_gaussian_ply(path, **{**good, field: value})
    assert list(tmp_path.iterdir()) == []
