"""Hostile and broken inputs through the real commands: each gives exit status 2 and one clear
message naming the file and the field, never a traceback, a hang or a write outside its folder.

Every row breaks a fresh copy of a valid capture / run / head / PLY (see ``conftest.py``). A new
reader or writer adds its rows here.
"""

import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch
from conftest import make_toy_model

from hostile import breakers as b
from hostile import pickle_bombs as pb
from mogaface.core.cli import main
from mogaface.core.io.ply import gaussian_property_names


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
    ("run-config-is-a-fifo", lambda c, t: ((c["run"] / "config.toml").unlink(), os.mkfifo(c["run"] / "config.toml"),
                                           _resume(c))[2], ["config.toml", "regular file"]),
    ("run-config-links-to-dev-zero", lambda c, t: ((c["run"] / "config.toml").unlink(),
                                                   (c["run"] / "config.toml").symlink_to("/dev/zero"), _resume(c))[2],
     ["config.toml", "regular file"]),
    ("run-config-over-the-size-limit", lambda c, t: (_pad(c["run"] / "config.toml", 2 * 2 ** 20), _resume(c))[1],
     ["config.toml", "over the limit"]),
    ("config-nested", lambda c, t: train(c, t, "--config", _config(t, "a = " + "[" * 100_000 + "]" * 100_000)),
     ["bad.toml", "nested too deeply"]),
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
    ("pickle-codecs-encode", lambda c, t: (b.codecs_encode_pickle(t / "m.pkl"),
                                           ["preview-head", t / "m.pkl", "--out", t / "p"])[1],
     ["m.pkl", "refused _codecs.encode('x', 'utf-8')", "'latin1'"]),
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
        ["import-ply", t / "x.ply", "--head", c["head"], "--out", t / "a.pt"])[1],
     ["x.ply", "'vertex'", "no Gaussians"]),
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
        0, -1)), ["render", c["run"], "--timesteps", "0", "--out", t / "r"])[1],
     ["avatar.pt", "'gaussians.binding'", "ids -1..", "expected ids in [0, "]),
    ("avatar-binding-past-the-faces", lambda c, t: (_avatar_edit(c["run"], lambda s: s["gaussians"]["binding"]
                                                                 .__setitem__(0, 10 ** 6)), _render(c, t))[1],
     ["avatar.pt", "'gaussians.binding'", "..1000000", "head.pkl has"]),
    ("avatar-no-gaussians", lambda c, t: (_avatar_edit(c["run"], lambda s: s.update(gaussians={
        k: v[:0] for k, v in s["gaussians"].items()})), _render(c, t))[1],
     ["avatar.pt", "'gaussians.binding'", "no Gaussians"]),
    ("render-huge-range", lambda c, t: ["render", c["run"], "--timesteps", "0-999999999999", "--out", t / "r"],
     ["timestep"]),
    ("demo-non-empty-out", lambda c, t: ((t / "d").mkdir(), (t / "d" / "keep.txt").write_text("mine"),
                                         ["demo", "--tiny", "--out", t / "d"])[2], ["not empty", "--overwrite"]),
    # outputs that are not files: never replaced (see test_outputs_that_are_not_files_are_kept)
    ("out-is-a-fifo", lambda c, t: (os.mkfifo(t / "o.ply"), _export(c, t / "o.ply"))[1],
     ["o.ply", "is a FIFO", "regular file only"]),
    ("out-is-a-folder", lambda c, t: ((t / "o.ply").mkdir(), _export(c, t / "o.ply"))[1], ["o.ply", "is a folder"]),
    ("out-is-a-socket", lambda c, t: (_socket(t / "o.ply"), _export(c, t / "o.ply"))[1], ["o.ply", "is a socket"]),
    ("out-links-to-dev-null", lambda c, t: ((t / "o.ply").symlink_to("/dev/null"), _export(c, t / "o.ply"))[1],
     ["o.ply", "symbolic link to a character device"]),
    ("out-links-to-a-folder", lambda c, t: ((t / "o.ply").symlink_to(t), _export(c, t / "o.ply"))[1],
     ["o.ply", "symbolic link to a folder"]),
    ("out-avatar-is-a-fifo", lambda c, t: (os.mkfifo(t / "a.pt"), ["import-ply", c["ply"], "--head", c["head"],
                                                                   "--out", t / "a.pt"])[1], ["a.pt", "is a FIFO"]),
    ("out-png-is-a-fifo", lambda c, t: ((t / "r").mkdir(), os.mkfifo(t / "r" / "00000_cam00.png"),
                                        ["render", c["run"], "--timesteps", "0", "--camera", "cam00",
                                         "--out", t / "r"])[2], ["00000_cam00.png", "is a FIFO"]),
    ("train-out-is-a-fifo", lambda c, t: (os.mkfifo(t / "newrun"), train(c, t))[1],
     ["newrun", "is a FIFO", "expected a folder"]),
    ("train-out-is-a-file", lambda c, t: ((t / "newrun").write_text("mine"), train(c, t))[1],
     ["newrun", "is a regular file", "expected a folder"]),
    ("train-out-under-a-file", lambda c, t: ((t / "f").write_text("mine"), ["train", c["capture"], "--out",
                                                                             t / "f" / "run", "--quiet"])[1],
     ["f: is a regular file, where a folder is needed"]),
    ("render-out-is-a-fifo", lambda c, t: (os.mkfifo(t / "r"), _render(c, t))[1], ["r", "is a FIFO",
                                                                                    "expected a folder"]),
    ("eval-out-is-a-device", lambda c, t: ["eval", c["run"], "--no-lpips", "--quiet", "--out", "/dev/null"],
     ["/dev/null", "is a character device", "expected a folder"]),
    ("eval-metrics-is-a-fifo", lambda c, t: ((t / "e").mkdir(), os.mkfifo(t / "e" / "metrics.json"),
                                             ["eval", c["run"], "--no-lpips", "--quiet", "--out", t / "e"])[2],
     ["metrics.json", "is a FIFO"]),
    ("events-log-links-out", lambda c, t: ((t / "mine.txt").write_text("mine"), (c["run"] / "events.jsonl").unlink(),
                                           (c["run"] / "events.jsonl").symlink_to(t / "mine.txt"),
                                           ["train", c["capture"], "--out", c["run"], "--resume", "--steps", "4",
                                            "--quiet"])[3], ["events.jsonl", "symbolic link"]),
    ("events-log-is-a-fifo", lambda c, t: ((c["run"] / "events.jsonl").unlink(), os.mkfifo(c["run"] / "events.jsonl"),
                                           ["train", c["capture"], "--out", c["run"], "--resume", "--steps", "4",
                                            "--quiet"])[2], ["events.jsonl", "FIFO"]),
    # torch files that declare more than they hold, or ask for code
    ("pt-deflated-2GiB", lambda c, t: (b.avatar_with(c["run"], "opacity_logit", lambda: torch.zeros(100_003),
                                                     marker=100_003, declared=2 ** 29, inflate=True), _render(c, t))[1],
     ["avatar.pt", "declares 21", "bytes of records in a file of"]),
    ("pt-storage-past-its-record", lambda c, t: (b.avatar_with(c["run"], "opacity_logit", lambda: torch.zeros(100_003),
                                                               marker=100_003, declared=2 ** 29), _render(c, t))[1],
     ["avatar.pt", "field 'data.pkl'", "536870912 elements", "its record holds 400012"]),
    ("pt-stride-zero-view", lambda c, t: (b.avatar_with(c["run"], "opacity_logit",
                                                        lambda: torch.zeros(1).expand(100_003), marker=100_003,
                                                        declared=2 ** 30), _render(c, t))[1],
     ["avatar.pt", "field 'data.pkl'", "(1073741824,)", "limit"]),
    ("pt-runs-code", lambda c, t: (_pickle_in_avatar(c["run"], {"x": b.RunsCode()}), _render(c, t))[1],
     ["avatar.pt", "refused to load global", "system"]),
    ("pt-is-a-fifo", lambda c, t: ((c["run"] / "avatar.pt").unlink(), os.mkfifo(c["run"] / "avatar.pt"),
                                   _render(c, t))[2], ["avatar.pt", "expected a regular file"]),
    ("pt-truncated", lambda c, t: (b.truncate(c["run"] / "avatar.pt"), _render(c, t))[1],
     ["avatar.pt", "not a torch archive", "truncated"]),
    ("pt-not-a-zip", lambda c, t: ((c["run"] / "avatar.pt").write_bytes(b"\x80\x02}q\x00."), _render(c, t))[1],
     ["avatar.pt", "not a torch archive"]),
    ("pt-active-sh-degree-7", lambda c, t: (_avatar_edit(c["run"], lambda s: s.update(active_sh_degree=7)),
                                            _render(c, t))[1], ["avatar.pt", "active_sh_degree", "[0, 3]"]),
    ("pt-sh-degree-text", lambda c, t: (_avatar_edit(c["run"], lambda s: s.update(max_sh_degree="x")),
                                        _render(c, t))[1], ["avatar.pt", "max_sh_degree"]),
    ("pt-colour-shape", lambda c, t: (_avatar_edit(c["run"], lambda s: s["gaussians"].update(
        sh_rest=torch.zeros(3, 2, 3))), _render(c, t))[1], ["avatar.pt", "gaussians.sh_rest", "expected shape"]),
    ("pt-binding-float", lambda c, t: (_avatar_edit(c["run"], lambda s: s["gaussians"].update(
        binding=s["gaussians"]["binding"].float())), _render(c, t))[1], ["avatar.pt", "gaussians.binding", "integer"]),
    ("pt-binding-2d", lambda c, t: (_avatar_edit(c["run"], lambda s: s["gaussians"].update(
        binding=s["gaussians"]["binding"][:, None])), _render(c, t))[1], ["avatar.pt", "gaussians.binding", "shape"]),
    # JSON files
    ("json-over-the-size-limit", lambda c, t: (_pad(c["capture"] / "transforms_train.json", 200 * 2 ** 20),
                                               cap(c))[1], ["transforms_train.json", "limit", "bytes"]),
    ("json-number-of-10000-digits", lambda c, t: ((c["capture"] / "transforms_train.json").write_text(
        '{"frames": ' + "1" * 10_000 + "}"), cap(c))[1], ["transforms_train.json", "unreadable JSON", "digits"]),
    ("json-many-values", lambda c, t: ((c["capture"] / "transforms_train.json").write_bytes(
        b'{"frames": [' + b",".join([b"{}"] * 6_000_000) + b"]}"), cap(c))[1],
     ["transforms_train.json", "holds up to 12000001 values", "limit"]),
    ("json-not-utf8", lambda c, t: ((c["capture"] / "transforms_train.json").write_bytes(b'{"a": "\xff"}'),
                                    cap(c))[1], ["transforms_train.json", "unreadable JSON"]),
    ("run-json-nested", lambda c, t: (b.nested_json(c["run"] / "run.json"), _render(c, t))[1],
     ["run.json", "nested too deeply"]),
    # images too small for the loss, and names that are not paths
    ("image-1x1", lambda c, t: (b.set_every_frame(c["capture"], w=1, h=1), cap(c))[1], ["w/h", "1x1", "smaller"]),
    ("image-3x7", lambda c, t: (b.set_every_frame(c["capture"], w=3, h=7), cap(c))[1], ["w/h", "3x7", "SSIM"]),
    ("image-10x32", lambda c, t: (b.set_every_frame(c["capture"], w=10), cap(c))[1], ["w/h", "10x32"]),
    ("image-0x0", lambda c, t: (b.set_every_frame(c["capture"], w=0, h=0), cap(c))[1], ["w", "positive integer"]),
    ("image-1x1-train", lambda c, t: (b.set_every_frame(c["capture"], w=1, h=1), train(c, t))[1], ["w/h", "1x1"]),
    ("file-path-nul", lambda c, t: (b.set_first_frame(c["capture"], file_path="images/00000_00.png\0.png"),
                                    cap(c))[1], ["transforms_train.json", "file_path", "control character '\\x00'"]),
    ("file-path-newline", lambda c, t: (b.set_first_frame(c["capture"], file_path="images/x\nerror: forged.png"),
                                        cap(c))[1], ["file_path", "control character '\\n'"]),
    ("mask-path-escape", lambda c, t: (b.set_first_frame(c["capture"], fg_mask_path="fg_masks/\x1b[2J.png"),
                                       cap(c))[1], ["fg_mask_path", "control character"]),
    ("flame-path-nul", lambda c, t: (b.set_first_frame(c["capture"], flame_param_path="flame_param/\0"), cap(c))[1],
     ["flame_param_path", "control character"]),
    ("run-json-capture-nul", lambda c, t: (b.edit_json(c["run"] / "run.json", lambda d: d.update(capture="a\0b")),
                                           _render(c, t))[1], ["run.json", "'capture'", "control character"]),
    ("model-file-nul", lambda c, t: (b.edit_json(c["capture"] / "capture_info.json",
                                                 lambda d: d.update(model_file="head\0.pkl")), train(c, t))[1],
     ["capture_info.json", "model_file", "control character"]),
    ("avatar-head-file-newline", lambda c, t: (_avatar_edit(c["run"], lambda s: s.update(head_file="head\n.pkl")),
                                               _render(c, t))[1], ["avatar.pt", "head_file"]),
    # numbers that are not what they should be
    ("matrix-nan", lambda c, t: (b.set_first_frame(c["capture"], transform_matrix=[[float("nan"), 0, 0, 0],
                                                                                    [0, 1, 0, 0], [0, 0, 1, 0],
                                                                                    [0, 0, 0, 1]]), cap(c))[1],
     ["transforms_train.json", "transform_matrix", "finite", "nan in row 0, column 0"]),
    ("matrix-3x4", lambda c, t: (b.set_first_frame(c["capture"], transform_matrix=[[1, 0, 0, 0]] * 3), cap(c))[1],
     ["transform_matrix", "got shape (3, 4)"]),
    ("npz-expression-scalar", lambda c, t: (_param_edit(c["capture"] / "flame_param" / "00000.npz",
                                                        expr=np.float32(1)), cap(c))[1],
     ["00000.npz", "'expr'", "(a single number)"]),
    ("npz-expression-empty", lambda c, t: (_param_edit(c["capture"] / "flame_param" / "00000.npz",
                                                       expr=np.zeros(0, np.float32)), cap(c))[1],
     ["00000.npz", "'expr'", "(no values)"]),
    ("npz-expression-over-the-model", lambda c, t: (_expression_of(c["capture"] / "flame_param", 25),
                                                    train(c, t))[1],
     ["flame_param/00000.npz", "'expr'", "at most 20 values", "found 25"]),
    ("npz-expression-over-the-model-render", lambda c, t: (shutil.copytree(c["capture"] / "flame_param", t / "p"),
                                                           _expression_of(t / "p", 25),
                                                           _render(c, t) + ["--params", t / "p"])[2],
     ["p/00000.npz", "'expr'", "at most 20 values", "found 25"]),
    ("npz-expression-over-the-model-in-the-run", lambda c, t: (_expression_of(c["run"] / "flame_param", 25),
                                                               _export(c, t / "o.ply"))[1],
     ["run/flame_param/00000.npz", "'expr'", "found 25"]),
    ("npz-60000-members", lambda c, t: (b.write_zip(c["capture"] / "flame_param" / "00000.npz", [
        (f"{i}.npy", b"", 0, 0, 0) for i in range(60_000)]), cap(c))[1],
     ["00000.npz", "declares 60000 zip members", "limit is 1024"]),
    ("npz-member-not-npy", lambda c, t: (_zip_member(c["capture"] / "flame_param" / "00000.npz", b"garbage"),
                                         cap(c))[1], ["00000.npz", "not a plain numpy archive"]),
    ("npz-declares-1e12-in-the-run", lambda c, t: (b.npz_declaring(c["run"] / "flame_param" / "00000.npz", "expr",
                                                                   (10 ** 12,)), _render(c, t))[1],
     ["00000.npz", "expr", "declares"]),
]


def _resume(c):
    return ["train", c["capture"], "--out", c["run"], "--resume", "--steps", "4", "--quiet"]


def _export(c, out):
    return ["export-ply", c["run"], "--timestep", "0", "--out", out]


def _render(c, t):
    return ["render", c["run"], "--timesteps", "0", "--out", t / "r"]


_SOCKETS = []


def _socket(path):
    import socket

    server = socket.socket(socket.AF_UNIX)
    server.bind(str(path))
    _SOCKETS.append(server)  # open until the test ends


def _pickle_in_avatar(run, obj):
    import pickle

    b.torch_declaring(run / "avatar.pt", {"x": torch.zeros(70_000)}, 70_000, 70_000,
                      pickle_bytes=pickle.dumps(obj, protocol=2))


def _pad(path, size):
    """The file grown to ``size`` bytes after its JSON (a sparse file: nothing is stored; the size alone is
    refused, before a byte is read)."""
    with open(path, "r+b") as handle:
        handle.seek(size - 1)
        handle.write(b" ")


def _param_edit(path, **arrays):
    from mogaface.core.io.npz import load_npz, save_npz

    params = load_npz(path)
    params.update(arrays)
    save_npz(path, params)


def _expression_of(folder, count):
    """Every FLAME parameter file in ``folder`` with ``count`` expression values (the head has 20)."""
    for path in sorted(folder.glob("*.npz")):
        _param_edit(path, expr=np.zeros((1, count), np.float32))


def _zip_member(path, data):
    import zipfile

    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("expr.npy", data)


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
    try:
        code, err = run_cli(argv, capsys)
    finally:
        while _SOCKETS:
            _SOCKETS.pop().close()
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


@pytest.mark.parametrize("make", ["fifo", "folder", "link-to-dev-null", "link-to-a-folder"])
def test_outputs_that_are_not_files_are_kept(copies, tmp_path, capsys, make):
    """What a refused output names is left exactly as it was (same kind, same inode, same link)."""
    out = tmp_path / "o.ply"
    {"fifo": lambda: os.mkfifo(out), "folder": out.mkdir, "link-to-dev-null": lambda: out.symlink_to("/dev/null"),
     "link-to-a-folder": lambda: out.symlink_to(tmp_path)}[make]()
    before = os.lstat(out)
    code, err = run_cli(_export(copies, out), capsys)
    after = os.lstat(out)
    assert code == 2 and "regular file only" in err
    assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino)
    if make == "link-to-dev-null":
        import stat

        assert os.readlink(out) == "/dev/null" and stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert not [p for p in tmp_path.iterdir() if ".partial" in p.name]


def test_an_output_linked_to_a_file_replaces_the_link_not_the_file(copies, tmp_path, capsys):
    mine = tmp_path / "mine.ply"
    mine.write_text("mine")
    out = tmp_path / "o.ply"
    out.symlink_to(mine)
    code, err = run_cli(_export(copies, out), capsys)
    assert code == 0, err
    assert not out.is_symlink() and out.read_bytes().startswith(b"ply\n") and mine.read_text() == "mine"


def test_a_landmark_embedding_npz_is_read_by_the_one_npz_reader(tmp_path):
    from mogaface.core.errors import InputError
    from mogaface.core.flame.landmarks import read_embedding

    path = tmp_path / "embedding.npz"
    b.npz_declaring(path, "lmk_faces_idx", (10 ** 12,))
    with pytest.raises(InputError, match=r"embedding.npz: field 'lmk_faces_idx': declares shape \(1000000000000,\)"):
        read_embedding(path)


@pytest.mark.parametrize("command", ["render", "eval"])
def test_an_output_folder_that_is_not_one_is_refused_before_any_work(copies, tmp_path, capsys, monkeypatch, command):
    from mogaface.core.run.folder import RunFolder

    def no_work(self):
        raise AssertionError("the avatar was loaded before the output was checked")

    monkeypatch.setattr(RunFolder, "load_avatar", no_work)
    os.mkfifo(tmp_path / "out")
    extra = ["--timesteps", "0"] if command == "render" else ["--no-lpips", "--quiet"]
    code, err = run_cli([command, copies["run"], *extra, "--out", tmp_path / "out"], capsys)
    assert code == 2 and f"{tmp_path / 'out'}: is a FIFO; expected a folder" in err, err
