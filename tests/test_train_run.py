"""The trainer on a tiny synthetic capture: learning, run folder, events, exact resume, signals."""

import json
import signal
import subprocess
import sys
import time

import pytest
import torch

from mogaface.core.avatar.avatar import Avatar
from mogaface.core.data.capture import Capture
from mogaface.core.errors import InputError
from mogaface.core.train import config as C
from mogaface.core.train.checkpoint import latest_checkpoint, load_checkpoint
from mogaface.core.train.trainer import Trainer


@pytest.fixture(scope="session")
def tiny_capture(tmp_path_factory):
    from mogaface.core.data.generator import CaptureSettings, make_capture

    root = tmp_path_factory.mktemp("tiny_capture")
    make_capture(root, CaptureSettings(views=3, timesteps=16, size=48, supersample=1), progress=False)
    return root


def tiny_config(**sections):
    base = {
        "train": {"steps": 12, "threads": 1, "log_every": 1, "checkpoint_every": 5, "keep_checkpoints": 2},
        "densify": {"start": 2, "stop": 10, "interval": 3, "grad_threshold": 1e-6, "opacity_reset_interval": 6,
                    "sh_degree_interval": 4, "max_gaussians": 20000, "percent_dense": 0.005},
        "eval": {"at_end": False, "lpips": False},
    }
    for name, values in sections.items():
        base.setdefault(name, {}).update(values)
    return C.resolve(overrides=base)


def read_events(run):
    return [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]


@pytest.fixture(scope="session")
def trained_run(tiny_capture, tmp_path_factory):
    run = tmp_path_factory.mktemp("run") / "run"
    config = tiny_config(train={"steps": 80, "checkpoint_every": 40},
                         densify={"start": 20, "stop": 60, "interval": 20, "opacity_reset_interval": 0},
                         eval={"at_end": True, "max_frames": 4})
    result = Trainer(tiny_capture, run, config).run()
    assert result == {"step": 80, "stopped": None, "complete": True}
    return run


def test_training_lowers_the_loss(trained_run):
    losses = [e["loss"] for e in read_events(trained_run) if e["event"] == "iter"]
    assert len(losses) == 80
    first, last = sum(losses[:8]) / 8, sum(losses[-8:]) / 8
    assert last < 0.6 * first


def test_run_folder_holds_everything(trained_run, tiny_capture):
    names = {p.name for p in trained_run.iterdir()}
    assert {"config.toml", "head.pkl", "run.json", "events.jsonl", "checkpoints", "avatar.pt", "flame_param",
            "metrics_train_end.json"} <= names
    info = json.loads((trained_run / "run.json").read_text())
    assert info["complete"] and info["final_step"] == 80 and info["capture"] == str(tiny_capture.resolve())
    assert info["background"] == [1.0, 1.0, 1.0] and info["head_file"] == "head.pkl"
    capture = Capture.open(tiny_capture)
    train_timesteps = sorted({f.timestep_index for f in capture.frames("train")})
    assert info["train_timesteps"] == train_timesteps
    assert sorted(p.name for p in (trained_run / "flame_param").iterdir()) == [f"{t:05d}.npz" for t in train_timesteps]
    tracked = capture.flame_params(train_timesteps[0])
    written = Capture._load_flame(trained_run / "flame_param" / f"{train_timesteps[0]:05d}.npz", None)
    assert all((written[k] == tracked[k]).all() for k in tracked)  # not fine-tuned: the tracked ones
    avatar = Avatar.load(trained_run / "avatar.pt")
    assert len(avatar.gaussians) == info["gaussians"]
    assert C.load(trained_run / "config.toml").train.steps == 80
    metrics = json.loads((trained_run / "metrics_train_end.json").read_text())
    assert metrics["split"] == "val" and metrics["frames"] == 4 and metrics["psnr"] > 10
    assert (trained_run / "checkpoints" / "latest").read_text().strip() == "step_000080.pt"


def test_events_file_format(trained_run):
    events = read_events(trained_run)
    assert events[0]["event"] == "start" and events[-1]["event"] == "done"
    for e in events:
        assert isinstance(e["event"], str) and isinstance(e["time"], float)
    iters = [e for e in events if e["event"] == "iter"]
    assert [e["step"] for e in iters] == list(range(1, 81))
    for key in ("loss", "l1", "ssim", "position", "scaling", "psnr", "gaussians", "it_s", "eta_s", "steps",
                "sh_degree", "elapsed_s"):
        assert key in iters[-1]
    assert iters[0]["eta_s"] is None and iters[1]["eta_s"] > 0  # the first window's pace includes compiling
    assert [e["step"] for e in events if e["event"] == "densify"] == [40, 60]
    assert [e["step"] for e in events if e["event"] == "checkpoint"] == [40, 80]


def test_checkpoints_load_weights_only_and_rotate(tiny_capture, tmp_path):
    run = tmp_path / "run"
    Trainer(tiny_capture, run, tiny_config(train={"checkpoint_every": 2})).run(until=9)
    files = sorted(p.name for p in (run / "checkpoints").glob("*.pt"))
    assert files == ["step_000008.pt", "step_000009.pt"]
    state = torch.load(latest_checkpoint(run / "checkpoints"), weights_only=True)
    assert state["step"] == 9 and state["format"] == "mogaface-train-checkpoint"


def final_tensors(run):
    state = load_checkpoint(latest_checkpoint(run / "checkpoints"))
    return state["avatar"]["gaussians"], state["optimizer"]["state"], state


def test_resume_continues_exactly(tiny_capture, tmp_path):
    config = tiny_config()
    straight, split = tmp_path / "straight", tmp_path / "split"
    Trainer(tiny_capture, straight, config).run()
    first = Trainer(tiny_capture, split, config).run(until=7)
    assert first == {"step": 7, "stopped": None, "complete": False}
    with pytest.raises(Exception, match="already holds a run"):
        Trainer(tiny_capture, split, config)
    Trainer(tiny_capture, split, resume=True).run()
    a, a_moments, a_state = final_tensors(straight)
    b, b_moments, b_state = final_tensors(split)
    assert a_state["step"] == b_state["step"] == 12
    assert len(a["binding"]) != 12620  # densification happened on the way
    for name in a:
        assert torch.equal(a[name], b[name]), name
    for index in a_moments:
        for key in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(a_moments[index][key], b_moments[index][key])
    assert torch.equal(a_state["rng"]["torch"], b_state["rng"]["torch"])
    assert a_state["densify"]["resets_done"] == b_state["densify"]["resets_done"] == 1
    assert [e["event"] for e in read_events(split)].count("resume") == 1


def test_a_step_cancelled_mid_render_resumes_exactly(tiny_capture, tmp_path, monkeypatch):
    """A signal that cancels step 7's render mid-way: that step is abandoned with its draws put
    back, the checkpoint is step 7, and resuming ends bit-identical to an uninterrupted run."""
    from mogaface.core.splat import cancel

    config = tiny_config()
    straight, split = tmp_path / "straight", tmp_path / "split"
    Trainer(tiny_capture, straight, config).run()
    render_view = Trainer._render_view

    def signalled_during_step_7(self, frame, index):
        if self.step == 7:
            self.request_stop(signal.SIGINT)  # what the handler does
            cancel.FLAG[0] = 1  # what the watcher thread does
        return render_view(self, frame, index)

    monkeypatch.setattr(Trainer, "_render_view", signalled_during_step_7)
    try:
        assert Trainer(tiny_capture, split, config).run() == {"step": 7, "stopped": signal.SIGINT, "complete": False}
    finally:
        cancel.FLAG[0] = 0
    monkeypatch.setattr(Trainer, "_render_view", render_view)
    Trainer(tiny_capture, split, resume=True).run()
    a, a_moments, a_state = final_tensors(straight)
    b, b_moments, b_state = final_tensors(split)
    for name in a:
        assert torch.equal(a[name], b[name]), name
    assert torch.equal(a_state["rng"]["torch"], b_state["rng"]["torch"])


def test_a_signal_during_the_final_evaluation_leaves_a_resumable_run(tiny_capture, tmp_path, monkeypatch):
    from mogaface.core.splat import cancel

    config = tiny_config(train={"steps": 3})
    run = tmp_path / "run"
    finish = Trainer.finish

    def cancelled(self):
        self.request_stop(signal.SIGINT)
        raise cancel.RenderCancelled("render cancelled by a signal")

    monkeypatch.setattr(Trainer, "finish", cancelled)
    assert Trainer(tiny_capture, run, config).run() == {"step": 3, "stopped": signal.SIGINT, "complete": False}
    assert load_checkpoint(latest_checkpoint(run / "checkpoints"))["step"] == 3
    monkeypatch.setattr(Trainer, "finish", finish)
    assert Trainer(tiny_capture, run, resume=True).run()["complete"]
    assert json.loads((run / "run.json").read_text())["complete"]


def test_a_metric_that_cannot_be_scored_at_the_end_never_loses_the_avatar(tiny_capture, tmp_path, monkeypatch):
    """Without the LPIPS weights (a Blender whose dependencies predate them), the run completes, the
    avatar is written, and the metrics and a warning say what was not scored and why."""
    from mogaface.core.for_blender.worker import TrainWorker
    from mogaface.core.metrics import lpips_weights

    monkeypatch.setenv(lpips_weights.ENV_VAR, str(tmp_path / "nowhere.ckpt"))
    run = tmp_path / "run"
    config = tiny_config(train={"steps": 3}, eval={"at_end": True, "lpips": True, "max_frames": 2})
    assert Trainer(tiny_capture, run, config).run()["complete"]
    assert (run / "avatar.pt").exists() and json.loads((run / "run.json").read_text())["complete"]
    metrics = json.loads((run / "metrics_train_end.json").read_text())
    assert metrics["psnr"] > 5 and "lpips" not in metrics
    assert "nowhere.ckpt: LPIPS AlexNet weights not found" in metrics["not_scored"]["lpips"]
    assert "Install Dependencies" in metrics["not_scored"]["lpips"]  # the way a Blender user gets them
    warnings = [e["message"] for e in read_events(run) if e["event"] == "warning"]
    assert len(warnings) == 1 and warnings[0].startswith("LPIPS not scored: ")
    worker = TrainWorker(["true"], run)  # what Blender's panel reports from these events
    for event in read_events(run):
        worker._apply(event)
    worker._finish(0)
    assert worker.progress.state == "done" and "finished at step 3; LPIPS not scored: " in worker.progress.message


def test_sigterm_checkpoints_and_resume_finishes(tiny_capture, tmp_path):
    run = tmp_path / "run"
    config = tmp_path / "tiny.toml"
    config.write_text(C.to_toml(tiny_config(train={"steps": 5000, "checkpoint_every": 0})))
    command = [sys.executable, "-m", "mogaface", "train", str(tiny_capture), "--out", str(run),
               "--config", str(config), "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            events = read_events(run) if (run / "events.jsonl").exists() else []
            if any(e["event"] == "iter" and e["step"] >= 3 for e in events):
                break
            assert process.poll() is None, process.communicate()
            time.sleep(0.2)
        process.send_signal(signal.SIGTERM)
        process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 128 + signal.SIGTERM
    events = read_events(run)
    stopped = events[-1]
    assert stopped["event"] == "stopped" and stopped["signal"] == "SIGTERM"
    assert load_checkpoint(latest_checkpoint(run / "checkpoints"))["step"] == stopped["step"]
    assert not (run / "avatar.pt").exists()
    finish = subprocess.run(command[:7] + ["--resume", "--steps", str(stopped["step"] + 2), "--quiet"],
                            capture_output=True, timeout=120)
    assert finish.returncode == 0, finish.stderr.decode()
    info = json.loads((run / "run.json").read_text())
    assert info["complete"] and info["final_step"] == stopped["step"] + 2
    assert (run / "avatar.pt").exists()


def test_flame_finetuning_moves_the_trained_timesteps(tiny_capture, tmp_path):
    run = tmp_path / "run"
    config = tiny_config(train={"steps": 6}, flame={"finetune": True, "joints_lr": 1e-3, "translation_lr": 1e-3})
    Trainer(tiny_capture, run, config).run()
    capture = Capture.open(tiny_capture)
    timesteps = json.loads((run / "run.json").read_text())["train_timesteps"]
    assert json.loads((run / "run.json").read_text())["flame_finetuned"]
    changed = 0
    for t in timesteps:
        written = Capture._load_flame(run / "flame_param" / f"{t:05d}.npz", None)
        tracked = capture.flame_params(t)
        assert (written["shape"] == tracked["shape"]).all()
        changed += any(not (written[k] == tracked[k]).all() for k in ("expr", "jaw_pose", "translation"))
    assert changed >= 3


def test_time_budget_finishes_early_with_results(tiny_capture, tmp_path):
    run = tmp_path / "run"
    result = Trainer(tiny_capture, run, tiny_config(train={"max_minutes": 1e-5})).run()
    assert result["complete"] and 1 <= result["step"] < 12
    info = json.loads((run / "run.json").read_text())
    assert info["time_limited"] and info["final_step"] == result["step"]
    assert (run / "avatar.pt").exists()
    assert any(e["event"] == "time_limit" for e in read_events(run))


def test_progressive_resolution_stages_double_to_full_size():
    from mogaface.core.train.schedule import image_scale

    config = tiny_config(train={"resolution_start": 0.25, "resolution_full": 0.5})
    assert [image_scale(config, p) for p in (0.0, 0.24, 0.25, 0.49, 0.5, 1.0)] == [0.25, 0.25, 0.5, 0.5, 1.0, 1.0]
    assert image_scale(tiny_config(), 0.0) == 1.0  # the default: full size throughout


def test_progressive_resolution_trains_on_smaller_images_then_full_size(tiny_capture, tmp_path, monkeypatch):
    from mogaface.core.data.target import area_resized
    from mogaface.core.train.training_view import ViewRenderer

    seen = []
    render = ViewRenderer.render

    def spy(self, frame, step, generator, scale=1.0):
        result = render(self, frame, step, generator, scale)
        seen.append((step, tuple(result.target.shape), tuple(result.render.rgb.shape)))
        return result

    monkeypatch.setattr(ViewRenderer, "render", spy)
    config = tiny_config(train={"steps": 8, "resolution_start": 0.5, "resolution_full": 0.5})
    trainer = Trainer(tiny_capture, tmp_path / "run", config)
    assert trainer.run()["complete"]
    full = tuple(trainer.data.target(trainer.data.frames[0]).shape)
    half = (round(full[0] / 2), round(full[1] / 2), 3)
    assert [shape for _, shape, _ in seen] == [half] * 4 + [full] * 4
    assert all(target == rgb for _, target, rgb in seen)  # the render at the target's size
    image = torch.rand(6, 8, 3)
    assert torch.allclose(area_resized(image, 4, 3)[1, 2], image[2:4, 4:6].mean(dim=(0, 1)))


def test_a_schedule_in_minutes_runs_through_the_budget_whatever_the_speed(tiny_capture, tmp_path):
    from mogaface.core.train.schedule import position_lr

    config = tiny_config(train={"steps": 1000, "max_minutes": 1.0, "schedule": "minutes", "resolution_start": 0.5},
                         densify={"start": 100, "stop": 900, "interval": 100, "opacity_reset_interval": 0,
                                  "sh_degree_interval": 100})
    trainer = Trainer(tiny_capture, tmp_path / "run", config)
    trainer.elapsed = 30.0  # half the budget in one step: the schedules stand at step 500
    assert (trainer.schedule_step(), trainer.progress()) == (500, 0.5)
    report = trainer.train_step()["densify"]
    assert report and trainer.avatar.gaussians.active_sh_degree == 3  # the pass at 500 ran; SH as at step 500
    group = next(g for g in trainer.optimizer.param_groups if g["name"] == "local_position")
    assert group["lr"] == position_lr(config, trainer.extent, 500)
    assert not trainer.train_step()["densify"]  # no time passed: nothing more is due
    trainer.elapsed = 48.0  # past the passes at 600, 700 and 800: the latest one runs, once
    passes, after_step = [], trainer.strategy.after_step
    trainer.strategy.after_step = lambda step, *rest: passes.append(step) or after_step(step, *rest)
    assert trainer.train_step()["densify"] and passes == [800]
    trainer.config.train.schedule = "steps"  # the default: the steps alone drive it, the time only ends the run
    assert trainer.schedule_step() == trainer.step == 3


def test_only_the_time_ends_a_run_whose_schedule_is_in_minutes(tiny_capture, tmp_path):
    config = tiny_config(train={"steps": 2, "max_minutes": 0.02, "schedule": "minutes", "checkpoint_every": 0})
    run = tmp_path / "run"
    result = Trainer(tiny_capture, run, config).run()
    assert result["complete"] and result["step"] > 2  # more steps than the schedule's length
    info = json.loads((run / "run.json").read_text())
    assert info["time_limited"] and info["final_step"] == result["step"]
    events = read_events(run)
    iters = [e for e in events if e["event"] == "iter"]
    assert iters[-1]["steps"] >= iters[-1]["step"] and any(e["event"] == "time_limit" for e in events)
    with pytest.raises(InputError, match="train.max_minutes > 0"):
        tiny_config(train={"schedule": "minutes"})
    with pytest.raises(InputError, match="train.schedule"):
        tiny_config(train={"schedule": "hours"})


def test_one_camera_has_the_extent_of_its_distance_to_the_head():
    """A tracked phone clip has one fixed camera: its spread is nothing, its distance to the head is
    the scene's size (3DGS's extent scales the position learning rate)."""
    from mogaface.core.camera import Camera
    from mogaface.core.train.data import camera_extent

    camera = Camera.look_at((0.0, 0.0, 0.6), (0.0, 0.0, 0.0), width=64, height=64, fx=60.0)
    assert camera_extent([camera, camera]) == pytest.approx(1.1 * 0.6)
    other = Camera.look_at((0.4, 0.0, 0.6), (0.0, 0.0, 0.0), width=64, height=64, fx=60.0)
    assert camera_extent([camera, other]) == pytest.approx(1.1 * 0.2)  # a rig: the spread, as 3DGS
