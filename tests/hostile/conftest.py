"""A tiny valid capture, head, trained run and binding PLY that each hostile case copies and breaks."""

import shutil

import pytest

from mogaface.core.cli import main


@pytest.fixture(scope="session")
def pristine(tmp_path_factory):
    """``{"capture", "run", "ply", "head"}`` built once: 3 views, 16 timesteps, 32 px, a 3-step run."""
    from mogaface.core.data.generator import CaptureSettings, make_capture
    from mogaface.core.train import config as C
    from mogaface.core.train.trainer import Trainer

    base = tmp_path_factory.mktemp("pristine")
    capture = base / "capture"
    make_capture(capture, CaptureSettings(views=3, timesteps=16, size=32, supersample=1), progress=False)
    run = base / "run"
    config = C.resolve(overrides={"train": {"steps": 3, "threads": 1, "checkpoint_every": 1, "keep_checkpoints": 3},
                                  "eval": {"at_end": False, "lpips": False}})
    Trainer(capture, run, config).run()
    ply = base / "binding.ply"
    assert main(["export-ply", str(run), "--binding-space", "--timestep", "0", "--out", str(ply)]) == 0
    return {"capture": capture, "run": run, "ply": ply, "head": run / "head.pkl"}


@pytest.fixture
def copies(pristine, tmp_path):
    """Fresh copies of the pristine inputs, free to break."""
    out = {}
    for name, path in pristine.items():
        target = tmp_path / path.name
        if path.is_dir():
            shutil.copytree(path, target)
        else:
            shutil.copyfile(path, target)
        out[name] = target
    return out
