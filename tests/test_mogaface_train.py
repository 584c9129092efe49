"""MoGaFace inside the trainer and evaluation: zero start, honest inputs, exact resume, exports."""

import numpy as np
import pytest
import torch

from mogaface.core.correction.model import MoGaFace
from mogaface.core.correction.training import centring_loss
from mogaface.core.data.capture import Capture
from mogaface.core.run.folder import load_flame_file
from mogaface.core.train import config as C
from mogaface.core.train.checkpoint import latest_checkpoint, load_checkpoint
from mogaface.core.train.correction_part import mogaface_world
from mogaface.core.train.trainer import Trainer

FULL = {"mode": "multi", "bank": True, "texture": True, "input_size": 32, "feature_dim": 16, "encoder_width": 4,
        "heads": 2, "hidden": 16, "plane_size": 8, "plane_dim": 4, "texture_hidden": 8, "encoder_views": 2}


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    from mogaface.core.data.generator import CaptureSettings, make_capture

    root = tmp_path_factory.mktemp("mogaface_capture")
    make_capture(root, CaptureSettings(views=3, timesteps=16, size=48, supersample=1), progress=False)
    return root


def config(steps=6, **mogaface):
    return C.resolve(overrides={
        "train": {"steps": steps, "threads": 1, "log_every": 1, "checkpoint_every": 3, "keep_checkpoints": 2},
        "densify": {"start": 2, "stop": 5, "interval": 2, "grad_threshold": 1e-6, "opacity_reset_interval": 0,
                    "sh_degree_interval": 2, "percent_dense": 0.005},
        "eval": {"at_end": False, "lpips": False},
        "mogaface": {**FULL, **mogaface},
    })


@pytest.fixture(scope="module")
def full_run(tiny_capture, tmp_path_factory):
    run = tmp_path_factory.mktemp("mogaface_run") / "run"
    Trainer(tiny_capture, run, config(steps=8)).run()
    return run


def test_baseline_has_no_modules(tiny_capture, tmp_path):
    trainer = Trainer(tiny_capture, tmp_path / "run", C.resolve(overrides={"eval": {"at_end": False}}))
    assert trainer.config.mogaface.mode == "off" and trainer.mogaface is None
    assert "mogaface" not in trainer.state()


def test_full_model_starts_at_the_baseline(tiny_capture, tmp_path):
    trainer = Trainer(tiny_capture, tmp_path / "run", config())
    frame = trainer.data.frames[0]
    _, world, correction = mogaface_world(trainer.mogaface, trainer.avatar, trainer.table, frame,
                                          trainer.background, 0, trainer.generator)
    with torch.no_grad():
        plain = trainer.avatar.gaussians.world(trainer.avatar.posed_vertices(trainer.table.params(frame.timestep_index)),
                                               trainer.avatar.flame.faces)
    for key in plain:
        assert torch.equal(world[key].detach(), plain[key]), key
    assert torch.count_nonzero(correction.expr_delta) == 0


def test_training_inputs_never_hold_the_scored_view(tiny_capture, tmp_path):
    multi = Trainer(tiny_capture, tmp_path / "multi", config())
    single = Trainer(tiny_capture, tmp_path / "single", config(mode="single", bank=False, texture=False))
    for frame in multi.data.frames:
        chosen = multi.mogaface.encoder_frames(frame, multi.generator)
        assert len(chosen) == 1 and frame.camera_id not in {f.camera_id for f in chosen}  # 2 training cameras
        assert {f.timestep_index for f in chosen} == {frame.timestep_index}
        one = single.mogaface.encoder_frames(frame, single.generator)
        assert len(one) == 1 and one[0].camera_id != frame.camera_id


def test_modules_learn_and_bank_fills(full_run):
    model = MoGaFace.load(full_run / "mogaface.pt")
    assert model.bank.written.any()
    assert torch.count_nonzero(model.head.out.weight) > 0  # the correction head moved off zero
    assert torch.count_nonzero(model.texture.heads["position"].weight) > 0


def test_corrected_flame_params_round_trip(full_run, tiny_capture):
    model = MoGaFace.load(full_run / "mogaface.pt")
    capture = Capture.open(tiny_capture)
    banked = 0
    for t in model.timesteps:
        corrected = load_flame_file(full_run / "flame_param_corrected" / f"{t:05d}.npz")
        used = load_flame_file(full_run / "flame_param" / f"{t:05d}.npz")
        tracked = capture.flame_params(t)
        for key in corrected:
            np.testing.assert_array_equal(corrected[key], used[key])
        np.testing.assert_array_equal(corrected["jaw_pose"], tracked["jaw_pose"])
        row = model.row[t]
        if model.bank.has(row):  # visited timestamps: the bank's mean; others: the regression
            banked += 1
            np.testing.assert_allclose(corrected["expr"], tracked["expr"] + model.bank.mean(row).numpy(), atol=1e-6)
    assert banked > 0


def test_resume_is_exact_with_modules_and_bank(tiny_capture, tmp_path):
    straight, split = tmp_path / "straight", tmp_path / "split"
    Trainer(tiny_capture, straight, config()).run()
    Trainer(tiny_capture, split, config()).run(until=4)
    Trainer(tiny_capture, split, resume=True).run()
    a = load_checkpoint(latest_checkpoint(straight / "checkpoints"))
    b = load_checkpoint(latest_checkpoint(split / "checkpoints"))
    assert a["step"] == b["step"] == 6
    for key, value in a["mogaface"]["model"].items():
        assert torch.equal(value, b["mogaface"]["model"][key]), key
    for index, moments in a["mogaface"]["optimizer"]["state"].items():
        for key in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(moments[key], b["mogaface"]["optimizer"]["state"][index][key])
    for key, value in a["avatar"]["gaussians"].items():
        assert torch.equal(value, b["avatar"]["gaussians"][key]), key


def test_evaluation_never_feeds_the_scored_view(full_run, tiny_capture, monkeypatch):
    from mogaface.core.correction.views import ViewImages
    from mogaface.core.evaluate.evaluation import evaluate_run
    from mogaface.core.evaluate.sources.corrected import MoGaFaceParams
    from mogaface.core.run.folder import RunFolder

    run = RunFolder(full_run)
    avatar = run.load_avatar()
    source = MoGaFaceParams(run.open_capture(), run, avatar.model, image_assisted=True)
    seen = []
    original = ViewImages.batch

    def spy(self, frames):
        seen.append([(f.timestep_index, f.camera_id) for f in frames])
        return original(self, frames)

    monkeypatch.setattr(ViewImages, "batch", spy)
    scored = []
    real = source.params_for

    def record(frame, exclude_view=None):
        scored.append((frame.timestep_index, frame.camera_id, exclude_view))
        before = len(seen)
        params = real(frame, exclude_view=exclude_view)
        for batch in seen[before:]:
            assert (frame.timestep_index, frame.camera_id) not in batch
        return params

    monkeypatch.setattr(source, "params_for", record)
    result = evaluate_run(full_run, max_frames=6, lpips=False, avatar=avatar, source=source,
                          out_dir=full_run / "eval_images", comparisons=0)
    assert all(camera == excluded for _, camera, excluded in scored)
    assert seen, "image-assisted inference looked at no view"
    assert source.inputs and all(scored_view not in views for scored_view, views in source.inputs)
    assert result["inference"].startswith("image-assisted")
    assert np.isfinite(result["protocols"]["self_reenactment"]["psnr"])


def test_centring_prior_pushes_against_the_running_mean(tiny_capture, tmp_path):
    trainer = Trainer(tiny_capture, tmp_path / "run", config(centring_weight=1.0))
    decay = trainer.config.mogaface.centring_decay
    trainer.mogaface.model.correction_mean.fill_(0.5)
    frame = trainer.data.frames[0]
    _, _, correction = mogaface_world(trainer.mogaface, trainer.avatar, trainer.table, frame,
                                      trainer.background, 0, trainer.generator)
    expr_delta = correction.expr_delta
    blended = decay * 0.5 + (1 - decay) * expr_delta.detach()
    gradient, = torch.autograd.grad(correction.centring, expr_delta, retain_graph=True)
    assert torch.allclose(gradient, blended)  # the push is the mean as this step leaves it
    assert correction.centring.item() == pytest.approx(float((blended ** 2).sum()) / (2 * (1 - decay)))
    assert "centring" in trainer.train_step()["losses"]
    with pytest.raises(Exception, match="centring_weight"):
        config(centring_weight=-1.0)
    with pytest.raises(Exception, match="centring_decay"):
        config(centring_decay=1.0)


def test_centring_prior_is_bounded_below_and_stops_at_a_zero_mean():
    running_mean = torch.tensor([0.3, -0.2])
    delta = torch.zeros(2, requires_grad=True)
    for _ in range(200):  # descent on Δψ alone: it settles where the running mean it leaves is zero
        loss = centring_loss(running_mean, delta, 0.9)
        assert loss.item() >= 0.0
        gradient, = torch.autograd.grad(loss, delta)
        delta = (delta - 5.0 * gradient).detach().requires_grad_(True)
    assert torch.allclose(0.9 * running_mean + 0.1 * delta.detach(), torch.zeros(2), atol=1e-5)


def test_rendered_targets_regress_a_known_offset(tiny_capture, tmp_path):
    trainer = Trainer(tiny_capture, tmp_path / "run", config(rendered_weight=1.0, rendered_views=2, rendered_offset=0.3))
    part = trainer.mogaface
    frame = trainer.data.frames[0]
    params = trainer.table.params(frame.timestep_index)
    inputs = [f for f in trainer.data.frames if f.timestep_index == frame.timestep_index]
    state = trainer.generator.get_state()
    loss = part.rendered_loss(trainer.avatar, params, inputs, trainer.background, trainer.generator)
    replay = torch.Generator()
    replay.set_state(state)
    offset = torch.randn(params["expr"][0].shape, generator=replay) * 0.3
    assert loss.item() == pytest.approx((offset**2).mean().item(), rel=1e-5)  # the head starts at zero
    loss.backward()
    assert torch.count_nonzero(part.model.head.out.bias.grad) > 0
    assert all(p.grad is None for p in trainer.avatar.gaussians.parameters())  # renders are targets only
    assert "rendered" in trainer.train_step()["losses"]
    with pytest.raises(Exception, match="rendered_offset"):
        config(rendered_offset=-0.1)


def test_rendered_views_are_the_avatar_seen_by_the_encoder(tiny_capture, tmp_path):
    from mogaface.core.correction.rendered_targets import render_views

    trainer = Trainer(tiny_capture, tmp_path / "run", config())
    frame = trainer.data.frames[0]
    camera = trainer.data.capture.camera(frame)
    with torch.no_grad():
        vertices = trainer.avatar.posed_vertices(trainer.table.params(frame.timestep_index))
        full = trainer.avatar.render_posed(vertices, camera, trainer.background).rgb.permute(2, 0, 1)
    same = render_views(trainer.avatar, vertices, [camera], camera.width, trainer.background)
    assert same.shape == (1, 3, camera.height, camera.width)
    assert torch.allclose(same[0], full.clamp(0, 1), atol=1e-6)
    half = render_views(trainer.avatar, vertices, [camera], camera.width // 2, trainer.background)
    pooled = torch.nn.functional.avg_pool2d(full.clamp(0, 1)[None], 2)[0]
    assert half.shape == (1, 3, camera.height // 2, camera.width // 2)
    error = (half[0] - pooled).abs().mean()
    assert error < 0.04 and error < 0.5 * (half[0] - pooled.flip(-1)).abs().mean()  # the same picture, smaller
