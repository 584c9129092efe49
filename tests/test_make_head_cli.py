"""``make-head`` and ``preview-head`` from the command line."""

import hashlib
import subprocess
import sys

import numpy as np
import torch

from mogaface.core.flame.model import FlameModel
from mogaface.core.io.image import read_image


def cli(*args):
    result = subprocess.run([sys.executable, "-m", "mogaface", *map(str, args)], capture_output=True, text=True, timeout=600)
    return result


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_make_head_is_deterministic_and_loads_in_both_formats(tmp_path, capsys):
    from mogaface.core.cli import main

    first, second, other, npz = tmp_path / "a.pkl", tmp_path / "b.pkl", tmp_path / "c.pkl", tmp_path / "a.npz"
    result = cli("make-head", first, "--subject", 0, "--seed", 5)  # the command line, once
    assert result.returncode == 0, result.stderr
    assert "expression components" in result.stdout
    for path, subject in ((second, 0), (other, 1), (npz, 0)):
        assert main(["make-head", str(path), "--subject", str(subject), "--seed", "5"]) == 0
        assert "expression components" in capsys.readouterr().out
    assert digest(first) == digest(second)
    assert digest(first) != digest(other)
    model = FlameModel.load(first)
    assert 3000 <= model.n_vertices <= 8000 and model.n_expr >= 12
    from_npz = FlameModel.load(npz)  # the same head, whichever file it was written to
    assert torch.equal(from_npz.v_template, model.v_template) and torch.equal(from_npz.exprdirs, model.exprdirs)


def test_make_head_refuses_unknown_suffix(tmp_path):
    result = cli("make-head", tmp_path / "head.obj")
    assert result.returncode == 2 and "head.obj" in result.stderr and ".pkl or .npz" in result.stderr
    assert not (tmp_path / "head.obj").exists()


def test_preview_head_writes_a_contact_sheet(tmp_path):
    from mogaface.core.cli import main

    assert main(["make-head", str(tmp_path / "head.pkl")]) == 0
    result = cli("preview-head", tmp_path / "head.pkl", "--out", tmp_path / "preview", "--size", "64")
    assert result.returncode == 0, result.stderr
    sheet = read_image(tmp_path / "preview" / "contact_sheet.png")
    assert sheet.shape[0] % 64 == 0 and sheet.shape[1] == 3 * 64
    neutral = read_image(tmp_path / "preview" / "neutral_front.png")[..., :3]
    jaw_open = read_image(tmp_path / "preview" / "jaw_open_front.png")[..., :3]
    # The head is in the frame (not all background) and opening the jaw changes the image.
    assert (neutral.mean(-1) < 0.9).mean() > 0.2
    assert np.abs(neutral - jaw_open).mean() > 0.005
