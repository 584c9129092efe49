"""Hostile and broken inputs through the real commands: each gives exit status 2 and one clear
message naming the file and the field, never a traceback, a hang or a write outside its folder.

Every row breaks a fresh copy of a valid capture / run / head / PLY (see ``conftest.py``). A new
reader or writer adds its rows here.
"""

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import torch

from mogaface.core.cli import main
from mogaface.core.io.ply import gaussian_property_names

from hostile import breakers as b
from hostile import pickle_bombs as pb
from conftest import make_toy_model


def run_cli(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.err


def cap(c, *rest):
    return ["check-capture", c["capture"], *rest]


def train(c, tmp, *rest):
    return ["train", c["capture"], "--out", tmp / "newrun", "--steps", "2", "--quiet", *rest]


def _config(tmp, text):
    path = tmp / "bad.toml"
    path.write_text(text)
    return path


def _avatar_edit(run, change):
    state = torch.load(run / "avatar.pt", weights_only=True)
    change(state)
    torch.save(state, run / "avatar.pt")


def _nan_position(state):
    state["gaussians"]["local_position"][0, 0] = float("nan")


def _model(tmp, **changes):
    model = make_toy_model()
    model.update(changes)
    path = tmp / "model.pkl"
    b.model_pickle(path, model)
    return path


def _sparse_huge(tmp):
    """A model whose J_regressor is a scipy csc_matrix that declares 10^6 x 10^6 (a few bytes stored)."""
    import pickle

    import scipy.sparse

    model = make_toy_model()
    matrix = scipy.sparse.csc_matrix((1, 1))
    matrix._shape = (10 ** 6, 10 ** 6)
    model["J_regressor"] = matrix
    path = tmp / "model.pkl"
    path.write_bytes(pickle.dumps(model, protocol=2))
    return path


# (id, prepare(copies, tmp) -> argv, substrings the error must hold)
CASES = [
    # captures: names that become files, intrinsics, sizes, bombs, structure
    ("camera-id-path", lambda c, t: (b.set_every_frame(c["capture"], camera_id="../../../../tmp/x/evil_cam"),
                                     cap(c))[1], ["camera_id", "plain name"]),
    ("camera-id-absolute", lambda c, t: (b.set_every_frame(c["capture"], camera_id="/etc/evil"), cap(c))[1],
     ["camera_id"]),
    ("focal-1e25", lambda c, t: (b.set_first_frame(c["capture"], fl_x=1e25), cap(c))[1], ["fl_x", "focal length"]),
    ("angle-1e-22", lambda c, t: (b.set_first_frame(c["capture"], camera_angle_x=1e-22, fl_x=None), cap(c))[1],
     ["focal length"]),
    ("principal-point-1e30", lambda c, t: (b.set_first_frame(c["capture"], cx=1e30), cap(c))[1], ["cx"]),
    ("image-13000-frame", lambda c, t: (b.set_every_frame(c["capture"], w=13000, h=13000), cap(c))[1],
     ["w/h", "limit"]),
    ("png-bomb-header", lambda c, t: (b.png_header_only(c["capture"] / "images" / "00000_00.png", 13000, 13000),
                                      cap(c))[1], ["00000_00.png", "13000x13000"]),
    ("png-truncated-full", lambda c, t: (b.truncate(c["capture"] / "images" / "00000_00.png"),
                                         cap(c, "--full"))[1], ["00000_00.png", "file_path", "unreadable image"]),
    ("npz-declares-1e12", lambda c, t: (b.npz_declaring(c["capture"] / "flame_param" / "00000.npz", "expr",
                                                        (10 ** 12,)), cap(c))[1], ["00000.npz", "expr", "declares"]),
    ("npz-inflates-20MB", lambda c, t: (b.npz_inflating(c["capture"] / "flame_param" / "00001.npz", "expr", 20),
                                        cap(c))[1], ["00001.npz", "expr", "declares"]),
    ("npz-long-expression", lambda c, t: (_long_expression(c["capture"] / "flame_param" / "00002.npz"), cap(c))[1],
     ["00002.npz", "expr", "limit"]),
    ("npz-object-member", lambda c, t: (b.npz_declaring(c["capture"] / "flame_param" / "00000.npz", "expr", (1,),
                                                        dtype="|O"), cap(c))[1], ["00000.npz", "object"]),
    ("json-nested", lambda c, t: (b.nested_json(c["capture"] / "transforms_train.json"), cap(c))[1],
     ["transforms_train.json", "nested too deeply"]),
    ("model-file-absolute", lambda c, t: (b.edit_json(c["capture"] / "capture_info.json",
                                                      lambda d: d.update(model_file="/etc/passwd")), train(c, t))[1],
     ["capture_info.json", "model_file"]),
    ("model-file-parent", lambda c, t: (b.edit_json(c["capture"] / "capture_info.json",
                                                    lambda d: d.update(model_file="../head.pkl")), train(c, t))[1],
     ["capture_info.json", "model_file"]),
    # settings
    ("grad-threshold-negative", lambda c, t: train(c, t, "--config", _config(t, "[densify]\ngrad_threshold = -1\n")),
     ["densify.grad_threshold", "must lie in"]),
    ("threads-100000", lambda c, t: train(c, t, "--config", _config(t, "[train]\nthreads = 100000\n")),
     ["train.threads", "must lie in"]),
    ("plane-size-100000", lambda c, t: train(c, t, "--config", _config(t, "[mogaface]\nplane_size = 100000\n")),
     ["mogaface.plane_size"]),
    ("lr-position-negative", lambda c, t: train(c, t, "--config", _config(t, "[lr]\nposition = -1\n")),
     ["lr.position"]),
    # head models
    ("model-zero-faces", lambda c, t: ["preview-head", _model(t, f=np.zeros((0, 3), np.int64)), "--out", t / "p"],
     ["model.pkl", "'f'", "found none"]),
    ("model-sparse-1e6x1e6", lambda c, t: ["preview-head", _sparse_huge(t), "--out", t / "p"],
     ["model.pkl", "J_regressor", "limit"]),
    ("pickle-reconstruct-bomb", lambda c, t: (b.raw_pickle(t / "m.pkl", {"v_template": b.Reconstruct((10 ** 10,))}),
                                              ["preview-head", t / "m.pkl", "--out", t / "p"])[1],
     ["m.pkl", "refused an array"]),
    ("pickle-nested-lists", lambda c, t: (b.shared_reference_pickle(t / "m.pkl"),
                                          ["preview-head", t / "m.pkl", "--out", t / "p"])[1],
     ["m.pkl", "counting a shared one"]),
    ("pickle-nested-lists-chumpy", lambda c, t: (b.shared_reference_pickle(t / "m.pkl", chumpy=True),
                                                 ["preview-head", t / "m.pkl", "--out", t / "p"])[1],
     ["m.pkl", "counting a shared one"]),
    ("pickle-many-arrays", lambda c, t: (b.raw_pickle(t / "m.pkl", {"x": b.many_arrays((500_000_000,), 6)}),
                                         ["preview-head", t / "m.pkl", "--out", t / "p"])[1],
     ["m.pkl", "in all"]),
    ("pickle-shared-references", lambda c, t: ((t / "m.pkl").write_bytes(pb.doubling_tuples(29)),
                                               ["preview-head", t / "m.pkl", "--out", t / "p"])[1],
     ["m.pkl", "counting a shared one each time it is reached"]),
    # PLY
    ("ply-1e15-vertices", lambda c, t: (b.ply_with_header(t / "x.ply", ["element vertex 1000000000000000",
                                                                        "property float x"]),
                                        ["import-ply", t / "x.ply", "--head", c["head"], "--out", t / "a.pt"])[1],
     ["x.ply", "vertex", "limit"]),
    ("ply-zero-vertices", lambda c, t: (b.ply_with_header(t / "x.ply", ["element vertex 0"] + [
        f"property float {n}" for n in gaussian_property_names(0)] + ["property int binding_0"]),
        ["import-ply", t / "x.ply", "--head", c["head"], "--out", t / "a.pt"])[1], ["binding", "no Gaussians"]),
    ("ply-duplicate-property", lambda c, t: (b.ply_with_header(t / "x.ply", ["element vertex 1", "property float x",
                                                                             "property float x"], bytes(8)),
                                             ["import-ply", t / "x.ply", "--head", c["head"], "--out", t / "a.pt"])[1],
     ["x.ply", "'x'", "twice"]),
    ("ply-is-a-folder", lambda c, t: ((t / "x.ply").mkdir(),
                                      ["import-ply", t / "x.ply", "--head", c["head"], "--out", t / "a.pt"])[1],
     ["x.ply", "folder"]),
    ("ply-nan-gaussian", lambda c, t: (_nan_ply(c["ply"]),
                                       ["import-ply", c["ply"], "--head", c["head"], "--out", t / "a.pt"])[1],
     ["binding.ply", "NaN"]),
    ("ply-negative-binding", lambda c, t: (_negative_binding_ply(c["ply"]),
                                           ["import-ply", c["ply"], "--head", c["head"], "--out", t / "a.pt"])[1],
     ["binding.ply", "binding_0"]),
    # runs
    ("avatar-nan-positions", lambda c, t: (_avatar_edit(c["run"], _nan_position),
                                           ["render", c["run"], "--timesteps", "0", "--out", t / "r"])[1],
     ["avatar.pt", "local_position", "NaN"]),
    ("avatar-head-file-escape", lambda c, t: (_avatar_edit(c["run"], lambda s: s.update(head_file="../../etc/passwd")),
                                              ["render", c["run"], "--timesteps", "0", "--out", t / "r"])[1],
     ["avatar.pt", "head_file", "plain name"]),
    ("avatar-negative-binding", lambda c, t: (_avatar_edit(c["run"], lambda s: s["gaussians"]["binding"].__setitem__(
        0, -1)), ["render", c["run"], "--timesteps", "0", "--out", t / "r"])[1], ["binding", "-1"]),
    ("render-huge-range", lambda c, t: ["render", c["run"], "--timesteps", "0-999999999999", "--out", t / "r"],
     ["timestep"]),
    ("demo-non-empty-out", lambda c, t: ((t / "d").mkdir(), (t / "d" / "keep.txt").write_text("mine"),
                                         ["demo", "--tiny", "--out", t / "d"])[2], ["not empty", "--overwrite"]),
]


def _long_expression(path):
    from mogaface.core.io.npz import load_npz, save_npz

    arrays = load_npz(path)
    arrays["expr"] = np.zeros((1, 100_000), np.float32)
    save_npz(path, arrays)


def _set_first_row(path, prop, value):
    """Overwrite one 4-byte property of the first vertex in our binary PLY (the writer refuses bad values)."""
    raw = path.read_bytes()
    head, _, body = raw.partition(b"end_header\n")
    table = np.frombuffer(body, dtype=np.uint8).copy()
    names = [line.split()[-1] for line in head.decode().splitlines() if line.startswith("property")]
    assert len(table) % (4 * len(names)) == 0  # every property is 4 bytes wide
    offset = 4 * names.index(prop)
    table[offset:offset + 4] = np.frombuffer(value.tobytes(), np.uint8)
    path.write_bytes(head + b"end_header\n" + table.tobytes())


def _nan_ply(path):
    _set_first_row(path, "y", np.float32("nan"))


def _negative_binding_ply(path):
    _set_first_row(path, "binding_0", np.int32(-5))


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_hostile_input_gives_a_clear_error(case, copies, tmp_path, capsys):
    _, prepare, expected = case
    argv = prepare(copies, tmp_path)
    code, err = run_cli(argv, capsys)
    assert code == 2, err
    assert err.startswith("error: ") and "Traceback" not in err
    for text in expected:
        assert text in err, (text, err)


def test_nothing_written_outside_the_output_folder(copies, tmp_path, capsys):
    """The camera-id escape is refused before anything is rendered: the target stays untouched."""
    target = tmp_path / "outside" / "evil_cam"
    target.parent.mkdir()
    b.set_every_frame(copies["capture"], camera_id=f"../../../../{target}")
    before = sorted(p.name for p in tmp_path.rglob("*.png") if "capture" not in str(p) and "run" not in str(p))
    code, err = run_cli(["render", copies["run"], "--timesteps", "0", "--out", tmp_path / "r",
                         "--capture", copies["capture"]], capsys)
    after = sorted(p.name for p in tmp_path.rglob("*.png") if "capture" not in str(p) and "run" not in str(p))
    assert code == 2 and "camera_id" in err
    assert before == after and not (tmp_path / "r").exists()


def test_demo_non_empty_out_keeps_the_users_files(tmp_path, capsys):
    out = tmp_path / "d"
    for name in ("run", "capture", "driver_capture"):
        (out / name).mkdir(parents=True)
        (out / name / "planted.txt").write_text("mine")
    code, err = run_cli(["demo", "--tiny", "--out", out], capsys)
    assert code == 2 and "--overwrite" in err
    assert all((out / n / "planted.txt").read_text() == "mine" for n in ("run", "capture", "driver_capture"))


@pytest.mark.parametrize("target", ["images/00000_00.png", "flame_param/00000.npz", "transforms_train.json"])
def test_fifo_in_place_of_a_file_is_refused_without_hanging(copies, target):
    path = copies["capture"] / target
    path.unlink()
    os.mkfifo(path)
    result = subprocess.run([sys.executable, "-m", "mogaface", "check-capture", str(copies["capture"])],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert pathlib.Path(target).name in result.stderr and "regular file" in result.stderr


def test_empty_and_extra_empty_arrays_round_trip_through_our_model_writer(tmp_path):
    from mogaface.core.flame.model_file import read_model_file
    from mogaface.core.flame.safe_pickle import load_model_pickle

    model = make_toy_model()
    model["extra_empty"] = np.zeros((0, 3))
    path = tmp_path / "m.pkl"
    b.model_pickle(path, model)
    raw = load_model_pickle(path)
    assert raw["extra_empty"].shape == (0, 3)
    assert np.array_equal(read_model_file(path).v_template, model["v_template"])
    # a reader we did not write agrees on the same bytes
    import pickle

    with open(path, "rb") as handle:
        other = pickle.load(handle, encoding="latin1")
    assert other["extra_empty"].shape == (0, 3)


def test_capture_writer_refuses_what_the_reader_refuses(tmp_path):
    from mogaface.core.data.writer import CaptureWriter
    from mogaface.core.errors import CaptureError

    writer = CaptureWriter(tmp_path / "cap")
    with pytest.raises(CaptureError, match="camera_id"):
        writer.camera_index("../evil")
    assert writer.camera_index("cam_07") == 0


def test_an_image_linked_from_outside_the_capture_is_refused(copies, tmp_path, capsys):
    image = copies["capture"] / "images" / "00000_00.png"
    outside = tmp_path / "elsewhere.png"
    outside.write_bytes(image.read_bytes())
    image.unlink()
    image.symlink_to(outside)
    code, err = run_cli(cap(copies), capsys)
    assert code == 2 and "00000_00.png" in err and "Traceback" not in err, err


def test_a_model_file_outside_the_capture_is_never_copied_into_the_run(copies, tmp_path, capsys):
    b.edit_json(copies["capture"] / "capture_info.json", lambda d: d.update(model_file="/etc/passwd"))
    code, err = run_cli(train(copies, tmp_path), capsys)
    assert code == 2 and "model_file" in err
    assert not (tmp_path / "newrun" / "head.pkl").exists()
