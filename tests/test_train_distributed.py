"""Data-parallel training with torchrun: two local ranks equal one process with the same batch.

The two-rank runs go through the real launcher (``python -m torch.distributed.run``, gloo on
CPU) and the real command line, so process-group setup, rank-0-only writing and failure reports
are the ones a user meets.
"""

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest
import torch

from mogaface.core.io.torch_file import load_torch_state
from mogaface.core.train import config as C
from mogaface.core.train.checkpoint import list_checkpoints, load_checkpoint
from mogaface.core.train.presets import FLAME_FINETUNE, FULL_METHOD
from mogaface.core.train.trainer import Trainer

SETTINGS = {
    "train": {"steps": 12, "threads": 1, "batch": 2, "log_every": 1, "checkpoint_every": 6, "keep_checkpoints": 3},
    "densify": {"start": 2, "stop": 10, "interval": 3, "grad_threshold": 1e-6, "opacity_reset_interval": 0,
                "sh_degree_interval": 4, "max_gaussians": 20000, "percent_dense": 0.005},
    "eval": {"at_end": False, "lpips": False},
    "mogaface": {**FULL_METHOD, "encoder_views": 2, "input_size": 32},
    "flame": FLAME_FINETUNE,
}


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from mogaface.core.data.generator import CaptureSettings, make_capture

    root = tmp_path_factory.mktemp("dist_capture")
    make_capture(root, CaptureSettings(views=4, timesteps=16, size=40, supersample=1), progress=False)
    return root


@pytest.fixture(scope="module")
def config_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("dist_config") / "config.toml"
    path.write_text(C.to_toml(C.resolve(overrides=SETTINGS)))
    return path


def torchrun(ranks: int, *args, **popen):
    """``torchrun --standalone --nproc_per_node ranks -m mogaface …`` (a free port each time)."""
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={ranks}",
               "-m", "mogaface", *map(str, args)]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen)


def avatar_tensors(state: dict) -> dict:
    return state["avatar"]["gaussians"] if "avatar" in state else state["gaussians"]


def assert_close_under_adam(x: torch.Tensor, y: torch.Tensor, lr: float, steps: int, name: str):
    """Equal within float tolerance, as Adam allows: most entries agree to 1e-5, 99 % to within one
    step of the learning rate, and none by more than ``steps`` of them. (With eps 1e-15 Adam turns a
    gradient of rounding-noise size into a full step whose sign the summation order decides.)"""
    d = (x.float() - y.float()).abs().flatten()
    assert float(d.median()) < 1e-5, (name, float(d.median()))
    assert float(torch.quantile(d, 0.99)) <= lr, (name, float(torch.quantile(d, 0.99)), lr)
    assert float(d.max()) <= steps * lr, (name, float(d.max()), lr)


def assert_same_training(a: dict, b: dict):
    """Two checkpoints hold the same avatar, FLAME table, bank and modules (float tolerance)."""
    ga, gb = avatar_tensors(a), avatar_tensors(b)
    assert torch.equal(ga["binding"], gb["binding"])  # identical densification decisions
    rates = {g["name"]: g["lr"] for g in a["optimizer"]["param_groups"]}
    assert a["step"] == a["config"]["train"]["steps"]  # the position rate has decayed to its last value
    rates["local_position"] /= a["config"]["lr"]["position_final_ratio"]  # its largest: the first step's
    for key in ga:
        if key != "binding":
            assert_close_under_adam(ga[key], gb[key], rates[key], a["step"], key)
    for key in ("expr", "jaw_pose", "translation"):
        assert_close_under_adam(a["table"][key], b["table"][key], rates[f"flame.{key}"], a["step"], key)
    module_lr = max(g["lr"] for g in a["mogaface"]["optimizer"]["param_groups"])
    for key, value in a["mogaface"]["model"].items():
        other = b["mogaface"]["model"][key]
        if value.is_floating_point():
            assert_close_under_adam(value, other, module_lr, a["step"], key)
        else:
            assert torch.equal(value, other), key


@pytest.fixture(scope="module")
def one_process(capture, config_file, tmp_path_factory):
    """The reference: one process, two views per step."""
    run = tmp_path_factory.mktemp("one") / "run"
    result = Trainer(capture, run, C.load(config_file)).run()
    assert result["complete"]
    return run


@pytest.fixture(scope="module")
def two_ranks(capture, config_file, tmp_path_factory):
    run = tmp_path_factory.mktemp("two") / "run"
    process = torchrun(2, "train", capture, "--out", run, "--config", config_file, "--quiet")
    out, err = process.communicate(timeout=600)
    assert process.returncode == 0, err[-3000:]
    return run


def test_two_ranks_train_the_same_avatar_as_one_process_with_the_batch(one_process, two_ranks):
    one = load_checkpoint(list_checkpoints(one_process / "checkpoints")[-1])
    two = load_checkpoint(list_checkpoints(two_ranks / "checkpoints")[-1])
    assert one["step"] == two["step"] == 12
    assert len(avatar_tensors(one)["binding"]) > 48  # densification ran (one Gaussian per triangle at start)
    assert_same_training(one, two)
    # The statistics reduced across ranks count each observation once.
    assert torch.allclose(one["densify"]["grad_count"], two["densify"]["grad_count"])
    assert torch.equal(one["table"]["expr"] != 0, two["table"]["expr"] != 0)
    # And they look the same: renders of the two avatars agree far beyond what training changes.
    a, b = render(one_process), render(two_ranks)
    assert psnr(a, b) > 45.0, psnr(a, b)
    assert psnr(a, render_initial(one_process)) < 35.0  # training did change the picture


def test_two_ranks_refine_the_cameras_as_one_process(capture, tmp_path):
    """Camera offsets' gradients are summed over the ranks like the Gaussians' (a Freeze run with
    refinement: the modules are left out, whose rounding-noise gradients Adam would amplify)."""
    settings = {**SETTINGS, "mogaface": {"mode": "off"}, "flame": {"finetune": False},
                "cameras": {"refine": True, "rotation_lr": 1e-3, "translation_lr": 1e-4}}
    config = tmp_path / "config.toml"
    config.write_text(C.to_toml(C.resolve(overrides=settings)))
    Trainer(capture, tmp_path / "one", C.load(config)).run()
    process = torchrun(2, "train", capture, "--out", tmp_path / "two", "--config", config, "--quiet")
    _, err = process.communicate(timeout=600)
    assert process.returncode == 0, err[-3000:]
    a, b = (load_checkpoint(list_checkpoints(tmp_path / run / "checkpoints")[-1]) for run in ("one", "two"))
    rates = {g["name"]: g["lr"] for g in a["optimizer"]["param_groups"]}
    assert a["cameras"]["ids"] == b["cameras"]["ids"]
    for key in ("rotation", "translation"):
        assert a["cameras"][key].abs().max() > 0, key
        assert_close_under_adam(a["cameras"][key], b["cameras"][key], rates[f"cameras.{key}"], a["step"], key)
    assert torch.equal(avatar_tensors(a)["binding"], avatar_tensors(b)["binding"])


def render(run, initial=False):
    from mogaface.core.avatar.avatar import Avatar
    from mogaface.core.train.data import TrainingData

    data = TrainingData(json.loads((run / "run.json").read_text())["capture"])
    avatar = Avatar.initial(run / "head.pkl", 3) if initial else Avatar.load(run / "avatar.pt")
    frame = data.frames[0]
    with torch.no_grad():
        return avatar.render(data.flame_table().params(frame.timestep_index), data.capture.camera(frame),
                             data.background).rgb


def render_initial(run):
    return render(run, initial=True)


def psnr(a, b):
    return float(-10 * torch.log10(((a - b) ** 2).mean()))


def test_rank_zero_alone_writes_the_run_folder(two_ranks):
    events = [json.loads(line) for line in (two_ranks / "events.jsonl").read_text().splitlines()]
    assert [e["event"] for e in events].count("start") == 1  # one writer of events
    assert [e["step"] for e in events if e["event"] == "iter"] == list(range(1, 13))
    assert (two_ranks / "avatar.pt").is_file() and (two_ranks / "mogaface.pt").is_file()
    assert json.loads((two_ranks / "run.json").read_text())["complete"] is True


def test_resume_with_another_world_size_continues_the_run(capture, config_file, one_process, two_ranks, tmp_path):
    """The two-rank run's step-6 checkpoint, resumed in one process, ends where one process ends."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(two_ranks, run)
    for path in list_checkpoints(run / "checkpoints"):
        if load_checkpoint(path)["step"] > 6:
            path.unlink()
    (run / "checkpoints" / "latest").unlink()
    (run / "avatar.pt").unlink()
    result = Trainer(capture, run, resume=True).run()
    assert result == {"step": 12, "stopped": None, "complete": True}
    assert_same_training(load_checkpoint(list_checkpoints(one_process / "checkpoints")[-1]),
                         load_checkpoint(list_checkpoints(run / "checkpoints")[-1]))
    d = (load_torch_state(run / "avatar.pt", "avatar")["gaussians"]["local_position"]
         - load_torch_state(one_process / "avatar.pt", "avatar")["gaussians"]["local_position"]).abs()
    assert float(torch.quantile(d.flatten(), 0.99)) < 1e-4


def _descendants(pid: int) -> list[int]:
    found, frontier = [], [pid]
    while frontier:
        parent = frontier.pop()
        for task in pathlib.Path(f"/proc/{parent}/task").glob("*"):
            children = (task / "children").read_text().split() if (task / "children").exists() else []
            found += [int(c) for c in children]
            frontier += [int(c) for c in children]
    return found


def _rank_of(pid: int) -> int | None:
    try:
        environ = pathlib.Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    except OSError:
        return None
    for entry in environ:
        if entry.startswith(b"RANK="):
            return int(entry[5:])
    return None


@pytest.mark.skipif(not pathlib.Path("/proc/self/task").is_dir(), reason="finds the rank by /proc (Linux)")
def test_a_killed_rank_is_reported_and_the_run_resumes(capture, config_file, tmp_path):
    run = tmp_path / "run"
    process = torchrun(2, "train", capture, "--out", run, "--config", config_file, "--steps", "100000",
                       "--quiet")
    try:
        deadline = time.monotonic() + 300
        while not list_checkpoints(run / "checkpoints") and time.monotonic() < deadline:
            assert process.poll() is None, process.communicate()[1][-3000:]
            time.sleep(0.2)
        assert list_checkpoints(run / "checkpoints"), "no checkpoint within the time allowed"
        workers = [p for p in _descendants(process.pid) if _rank_of(p) == 1]
        assert workers, "rank 1 not found"
        os.kill(workers[0], signal.SIGKILL)
        _, err = process.communicate(timeout=240)  # reported and ended, not a hang
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode != 0
    assert "rank" in err.lower() and ("SIGKILL" in err or "Signal 9" in err or "exitcode" in err.lower()), err[-3000:]
    saved = load_checkpoint(list_checkpoints(run / "checkpoints")[-1])["step"]
    trainer = Trainer(capture, run, resume=True)
    assert trainer.step == saved
    result = trainer.run(until=saved + 2)
    assert result["step"] == saved + 2 and not result["complete"]


def test_launcher_prefix_replaces_the_interpreter():
    from mogaface.core.errors import InputError
    from mogaface.core.for_blender.launcher import with_launcher
    from mogaface.core.for_blender.worker import train_command

    command = train_command("/usr/bin/python3", "/data/cap", "/data/run", preset="demo", threads=1)
    assert with_launcher(command, "") == command
    launched = with_launcher(command, "torchrun --nproc_per_node 2 --nnodes 1")
    assert launched[:5] == ["torchrun", "--nproc_per_node", "2", "--nnodes", "1"]
    assert launched[5:8] == ["-m", "mogaface", "train"] and launched[8:] == command[command.index("train") + 1:]
    assert "/usr/bin/python3" not in launched and "-I" not in launched
    with pytest.raises(InputError, match="launcher"):
        with_launcher(command, "torchrun 'unclosed")


def test_a_launched_run_gives_each_rank_an_image_and_keeps_the_images_seen():
    from mogaface.core.for_blender.launcher import launcher_arguments
    from mogaface.core.train.config import BATCH_RULES, LAUNCHED_BATCH_RULE

    assert launcher_arguments("torchrun --nproc_per_node 2", resume=False) == [
        "--batch", "auto", "--batch-rule", LAUNCHED_BATCH_RULE]
    assert LAUNCHED_BATCH_RULE in BATCH_RULES
    assert launcher_arguments("  ", resume=False) == [] and launcher_arguments("torchrun", resume=True) == []


def test_a_worker_started_by_torchrun_reports_progress_and_cancels_with_a_checkpoint(capture, config_file, tmp_path):
    """What the Blender panel and the headless script do with a launcher in the preferences."""
    from mogaface.core.for_blender.launcher import with_launcher
    from mogaface.core.for_blender.worker import TrainWorker, train_command

    run = tmp_path / "run"
    launcher = f"{sys.executable} -m torch.distributed.run --standalone --nproc_per_node 2"
    command = with_launcher(train_command(sys.executable, capture, run, steps=100000, extra=["--config",
                                                                                           str(config_file)]),
                            launcher)
    worker = TrainWorker(command, run, env={**os.environ, "OMP_NUM_THREADS": "1"}).start()
    deadline = time.monotonic() + 300
    while worker.poll().step < 3 and not worker.progress.finished and time.monotonic() < deadline:
        time.sleep(0.2)
    assert worker.progress.step >= 3, worker.stderr_tail()
    worker.cancel()
    progress = worker.wait(interval=0.2, timeout=240)
    assert progress.state == "cancelled", (progress.message, worker.stderr_tail())
    stopped = [e for e in worker.events if e["event"] == "stopped"]
    assert len(stopped) == 1  # one writer
    assert load_checkpoint(list_checkpoints(run / "checkpoints")[-1])["step"] == stopped[0]["step"]
