"""Shared material of the evaluation, render and export tests: one tiny capture and fake runs.

The capture is made once per session (it is the slow part); a fake run is an untrained avatar
(``Avatar.initial`` with seeded random Gaussians) saved the way the trainer lays out a run.
"""

import json
import pathlib
import shutil

import numpy as np
import pytest
import torch

from mogaface.core.avatar.avatar import Avatar
from mogaface.core.avatar.gaussians import BoundGaussians
from mogaface.core.data import layout
from mogaface.core.data.capture import Capture
from mogaface.core.data.generator import CaptureSettings, make_capture
from mogaface.core.io.npz import save_npz
from mogaface.core.run.folder import RunFolder

_CACHE: dict = {}
EXPR_NUDGE = 0.5  # added to expr[0] of the run's timestep-0 parameters, as training would


def tiny_capture_like(tmp_path_factory, name: str, **changes) -> pathlib.Path:
    """A capture of the tiny one's size (3 views, 16 timesteps, 48 px) with other settings, in a new folder."""
    root = tmp_path_factory.mktemp(name)
    make_capture(root, CaptureSettings(views=3, timesteps=16, size=48, supersample=1, **changes), progress=False)
    return root


def tiny_capture(tmp_path_factory) -> pathlib.Path:
    """3 views, 16 timesteps + 2 of VAL, 48 px (train: cam00/cam02 at 0-11; val: cam01; test: FREE 12-15, VAL 16-17)."""
    if "capture" not in _CACHE:
        root = tmp_path_factory.mktemp("capture")
        _CACHE["capture"] = make_capture(root, CaptureSettings(views=3, timesteps=16, size=48, supersample=1), progress=False)
    return _CACHE["capture"]


def random_avatar(head_file, seed: int = 0, active_sh_degree: int = 1, count: int = 3000) -> Avatar:
    """An untrained avatar: ``count`` seeded random Gaussians on random triangles (several share
    some, many have none), every SH band filled but only ``active_sh_degree`` in use."""
    avatar = Avatar.initial(head_file)
    gen = torch.Generator().manual_seed(seed)
    faces = torch.randint(0, len(avatar.gaussians), (count,), generator=gen)
    tensors = {k: v.detach()[faces] for k, v in avatar.gaussians.tensors().items()}
    avatar.gaussians = BoundGaussians(tensors.pop("binding"), avatar.gaussians.max_sh_degree, **tensors)
    g = avatar.gaussians
    n = len(g)
    with torch.no_grad():
        g.local_position += 0.3 * torch.randn(n, 3, generator=gen)
        g.local_log_scale += 0.3 * torch.randn(n, 3, generator=gen) - 0.3
        g.local_rotation.copy_(torch.randn(n, 4, generator=gen))
        g.opacity_logit.copy_(torch.randn(n, generator=gen) + 1.0)
        g.sh_dc.copy_(torch.randn(n, 1, 3, generator=gen))
        g.sh_rest.copy_(0.3 * torch.randn(*g.sh_rest.shape, generator=gen))
    g.active_sh_degree = active_sh_degree
    return avatar


def make_fake_run(root: pathlib.Path, capture_root: pathlib.Path, seed: int = 0) -> pathlib.Path:
    """A run folder as the trainer writes it: avatar.pt beside head.pkl, flame_param/, run.json."""
    root.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(capture_root / "head.pkl", root / "head.pkl")
    random_avatar(root / "head.pkl", seed).save(root / "avatar.pt")
    capture = Capture.open(capture_root)
    trained = sorted({f.timestep_index for f in capture.frames("train")})
    for t in trained:
        params = dict(capture.flame_params(t))
        params["shape"] = params["shape"] + 0.1  # the identity training refined
        if t == 0:
            params["expr"] = params["expr"].copy()
            params["expr"][0] += EXPR_NUDGE
        save_npz(root / "flame_param" / f"{t:05d}.npz", layout.batched_flame_params(params))
    (root / "run.json").write_text(json.dumps({"capture": str(capture_root.resolve()), "background": [1.0, 1.0, 1.0]}))
    return root


def fake_run(tmp_path_factory) -> pathlib.Path:
    if "run" not in _CACHE:
        _CACHE["run"] = make_fake_run(tmp_path_factory.mktemp("run"), tiny_capture(tmp_path_factory))
    return _CACHE["run"]


def driver_capture(tmp_path_factory) -> pathlib.Path:
    """Subject B: the tiny capture's files with another identity and other expressions."""
    if "driver" not in _CACHE:
        source = tiny_capture(tmp_path_factory)
        root = tmp_path_factory.mktemp("driver") / "capture_b"
        shutil.copytree(source, root, ignore=shutil.ignore_patterns("images", "fg_masks", "flame_param_gt"))
        for t in Capture.open(source).timesteps:
            path = root / layout.flame_param_path(t)
            params = layout.normalize_flame_params(dict(np.load(path)), path)
            params["shape"] = params["shape"] - 1.0
            params["expr"] = params["expr"][::-1].copy()
            save_npz(path, layout.batched_flame_params(params))
        _CACHE["driver"] = root
    return _CACHE["driver"]


def render_np(avatar, params, camera, background=(1.0, 1.0, 1.0)):
    from mogaface.core.avatar.avatar import flame_params_to_torch

    with torch.no_grad():
        out = avatar.render(flame_params_to_torch(params), camera, background)
    return out.rgb.numpy(), out.alpha.numpy()


@pytest.fixture(scope="module", name="capture")
def capture_fixture(tmp_path_factory):
    """The tiny capture, opened (a test module imports this fixture to use ``capture``)."""
    return Capture.open(tiny_capture(tmp_path_factory))


@pytest.fixture(scope="module", name="run")
def run_fixture(tmp_path_factory):
    """A fake run on the tiny capture, opened (imported as ``run_fixture``, used as ``run``)."""
    return RunFolder(fake_run(tmp_path_factory))


def watch_target_images(monkeypatch) -> list[tuple[str, int]]:
    """Record ``(camera id, timestep)`` of every target image the evaluation protocols load."""
    from mogaface.core.evaluate import protocols

    loaded = []
    real_target = protocols.target_image

    def spy(capture, frame, *args):
        loaded.append((frame.camera_id, frame.timestep_index))
        return real_target(capture, frame, *args)

    monkeypatch.setattr(protocols, "target_image", spy)
    return loaded
