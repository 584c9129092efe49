"""Run folders under stress: two writers, stale locks, killed writers' temporary files, damaged
checkpoints, full or read-only disks, interrupts at any moment."""

import errno
import json
import os
import pathlib
import signal
import stat
import subprocess
import sys
import tempfile
import time

import numpy as np
import pytest
import torch

from mogaface.core.cli import main
from mogaface.core.errors import InputError
from mogaface.core.train import config as C
from mogaface.core.train.checkpoint import latest_checkpoint, load_checkpoint, resumable
from mogaface.core.train.run_lock import RunLock
from mogaface.core.train.trainer import Trainer


def events(run):
    return [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]


def resumed(c, steps):
    config = C.resolve(path=c["run"] / "config.toml", overrides={"train": {"steps": steps}})
    return Trainer(c["capture"], c["run"], config, resume=True)


def warnings_of(run):
    return [e["message"] for e in events(run) if e["event"] == "warning"]


def test_second_writer_is_refused_with_the_owners_pid(copies, capsys):
    with RunLock(copies["run"]):
        code = main(["train", str(copies["capture"]), "--out", str(copies["run"]), "--resume", "--steps", "5",
                     "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and f"in use by another training process (pid {os.getpid()})" in err
    assert load_checkpoint(latest_checkpoint(copies["run"] / "checkpoints"))["step"] == 3  # untouched


def test_two_train_processes_on_one_fresh_folder(copies, tmp_path):
    out = tmp_path / "shared"
    config = tmp_path / "long.toml"
    config.write_text(C.to_toml(C.resolve(overrides={"train": {"steps": 100000, "threads": 1, "checkpoint_every": 0},
                                                     "eval": {"at_end": False, "lpips": False}})))
    command = [sys.executable, "-m", "mogaface", "train", str(copies["capture"]), "--out", str(out), "--config",
               str(config), "--quiet"]
    first = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 180
        while not ((out / "events.jsonl").exists() and any(e["event"] == "iter" for e in events(out))):
            assert first.poll() is None and time.monotonic() < deadline, first.communicate()
            time.sleep(0.2)
        second = subprocess.run(command, capture_output=True, text=True, timeout=180)
        assert second.returncode == 2
        assert f"in use by another training process (pid {first.pid})" in second.stderr
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 128 + signal.SIGTERM
    assert [e["event"] for e in events(out)].count("start") == 1


def test_stale_lock_partials_and_a_truncated_checkpoint_on_resume(copies):
    run = copies["run"]
    (run / ".lock").write_text("999999\n")  # a killed writer's pid; no process holds the lock
    partial = run / "checkpoints" / ".step_000004.abc123.partial.pt"
    partial.write_bytes(b"half a checkpoint")
    newest = latest_checkpoint(run / "checkpoints")
    newest.write_bytes(newest.read_bytes()[:1000])
    result = resumed(copies, 5).run()
    assert result == {"step": 5, "stopped": None, "complete": True}
    notes = warnings_of(run)
    assert any("999999" in n for n in notes)
    assert any("removed 1 unfinished temporary file" in n for n in notes)
    assert any("skipped a damaged checkpoint" in n and "step_000003.pt" in n for n in notes)
    assert any("resuming from step_000002.pt" in n for n in notes)
    assert not partial.exists()
    assert [e for e in events(run) if e["event"] == "resume"][-1]["step"] == 2


def test_no_intact_checkpoint_is_a_clear_error(copies):
    for path in (copies["run"] / "checkpoints").glob("step_*.pt"):
        path.write_bytes(b"")
    with pytest.raises(InputError, match="no intact checkpoint to resume from"):
        resumed(copies, 5)


def test_disk_full_during_a_checkpoint(copies, monkeypatch):
    trainer = resumed(copies, 5)

    def full_disk(state, path):
        with open(path, "wb") as handle:
            handle.write(b"partial")
        raise RuntimeError("PytorchStreamWriter failed writing file data/0: file write failed")

    monkeypatch.setattr(torch, "save", full_disk)
    with pytest.raises(InputError, match="cannot write .disk full or not writable") as raised:
        trainer.checkpoint()
    assert raised.value.path == str(copies["run"] / "checkpoints" / f"step_{trainer.step:06d}.pt")  # not the temporary
    assert ".partial" not in str(raised.value)
    assert not [p for p in (copies["run"] / "checkpoints").iterdir() if ".partial" in p.name]
    assert load_checkpoint(latest_checkpoint(copies["run"] / "checkpoints"))["step"] == 3


def test_read_only_output_is_a_clear_error(copies, tmp_path, monkeypatch, capsys):
    def refuse(*args, dir=None, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", dir)

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    code = main(["render", str(copies["run"]), "--timesteps", "0", "--out", str(tmp_path / "ro")])
    err = capsys.readouterr().err
    assert code == 2 and "Permission denied" in err and "Traceback" not in err


def test_disk_full_while_writing_an_image_names_the_image(tmp_path, monkeypatch):
    """A write into the temporary that fails naming no file (PIL's) is said of the output's own name."""
    from PIL import Image

    from mogaface.core.io.image import write_png

    def full_disk(self, path, *args, **kwargs):
        pathlib.Path(path).write_bytes(b"partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", full_disk)
    with pytest.raises(OSError, match="No space left on device") as raised:
        write_png(tmp_path / "a.png", np.zeros((4, 4, 3), np.float32))
    assert raised.value.filename == str(tmp_path / "a.png") and list(tmp_path.iterdir()) == []


def test_run_folder_that_cannot_be_created(copies, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    with pytest.raises(InputError, match="a_file: is a regular file, where a folder is needed to hold"):
        Trainer(copies["capture"], blocker / "run")


def test_corrupt_image_mid_run_keeps_the_steps_done(copies, tmp_path):
    for image in (copies["capture"] / "images").glob("*_00.png"):  # every image of one training camera
        image.write_bytes(image.read_bytes()[:60])
    run = tmp_path / "fresh_run"
    config = C.resolve(overrides={"train": {"steps": 200, "threads": 1, "checkpoint_every": 0, "log_every": 1},
                                  "eval": {"at_end": False, "lpips": False}})
    trainer = Trainer(copies["capture"], run, config)
    with pytest.raises(InputError, match="_00.png"):
        trainer.run()
    done = [e["step"] for e in events(run) if e["event"] == "iter"]
    assert load_checkpoint(latest_checkpoint(run / "checkpoints"))["step"] == (done[-1] if done else 0)


def _train_process(copies, tmp_path, sigint_ignored: bool = False):
    """``train`` in a child; ``sigint_ignored``: started as a script's background job is (SIGINT
    ignored, inherited across exec)."""
    config = tmp_path / "long.toml"
    config.write_text(C.to_toml(C.resolve(overrides={"train": {"steps": 100000, "threads": 1, "checkpoint_every": 0},
                                                     "eval": {"at_end": False, "lpips": False}})))
    out = tmp_path / "sig"
    command = [sys.executable, "-m", "mogaface", "train", str(copies["capture"]), "--out", str(out), "--config",
               str(config), "--quiet"]
    disposition = signal.SIG_IGN if sigint_ignored else signal.SIG_DFL
    return subprocess.Popen(command, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, disposition)), out


def _signalled(process, when, *signals) -> str:
    """Send ``signals`` to the training child once ``when()`` returns; its stderr. A child that
    missed them is killed: it must not train on after the test."""
    try:
        when()
        for number in signals:
            process.send_signal(number)
        return process.communicate(timeout=120)[1]
    finally:
        if process.poll() is None:
            process.kill()


def _wait_until(process, ready, poll_s=0.2):
    """Until ``ready()``, the training child running all along (a harness deadline against a hang)."""
    deadline = time.monotonic() + 180
    while not ready():
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(poll_s)


def _wait_for_first_step(process, out):
    """Until the training child has logged a step."""
    _wait_until(process, lambda: (out / "events.jsonl").exists() and any(e["event"] == "iter" for e in events(out)))


def test_interrupt_during_start_up_exits_quietly(copies, tmp_path):
    process, _ = _train_process(copies, tmp_path)
    err = _signalled(process, lambda: time.sleep(1.0), signal.SIGINT)  # importing torch and numba
    assert process.returncode == 128 + signal.SIGINT, err
    assert "Traceback" not in err


def test_interrupt_while_the_trainer_starts_is_not_lost_when_the_parent_ignores_sigint(copies, tmp_path):
    """A script's ``&`` job (Blender's worker may be one) hands its children SIGINT ignored; the
    cancel must still stop the run when it lands after the imports, before the trainer's handler."""
    process, out = _train_process(copies, tmp_path, sigint_ignored=True)
    # the run folder made: the imports are done, the trainer is starting
    err = _signalled(process, lambda: _wait_until(process, out.exists, poll_s=0.02), signal.SIGINT)
    assert process.returncode == 128 + signal.SIGINT, err
    assert "Traceback" not in err


def test_double_interrupt_exits_with_the_signal_status(copies, tmp_path):
    process, out = _train_process(copies, tmp_path)
    err = _signalled(process, lambda: _wait_for_first_step(process, out), signal.SIGINT, signal.SIGINT)
    assert process.returncode == 128 + signal.SIGINT, err
    assert "Traceback" not in err
    assert not [p for p in (out / "checkpoints").glob(".*")] if (out / "checkpoints").exists() else True


def test_interrupt_while_training_checkpoints_the_step_before_the_cancelled_render(copies, tmp_path):
    """The first SIGINT also cancels the render under way (the flag the kernels poll); the step it
    belonged to is abandoned and its draw from the sampler put back, so the checkpoint is a clean
    step boundary that resumes."""
    process, out = _train_process(copies, tmp_path)
    err = _signalled(process, lambda: _wait_for_first_step(process, out), signal.SIGINT)
    assert process.returncode == 128 + signal.SIGINT and "Traceback" not in err, err
    assert [e for e in events(out) if e["event"] == "stopped"][-1]["signal"] == "SIGINT"
    state = load_checkpoint(latest_checkpoint(out / "checkpoints"))
    iters = [e["step"] for e in events(out) if e["event"] == "iter"]
    assert state["step"] >= iters[-1]
    sampler = state["sampler"]  # one frame drawn per step (batch 1): nothing drawn for the abandoned step
    assert sampler["position"] == state["step"] % len(sampler["order"]) or sampler["position"] == len(sampler["order"])
    config = C.resolve(path=out / "config.toml", overrides={"train": {"steps": state["step"] + 1}})
    assert Trainer(copies["capture"], out, config, resume=True).run()["step"] == state["step"] + 1


def test_the_cancel_flag_stops_a_running_raster_kernel():
    """A flag set by another thread while the kernel runs (nogil) stops it part-way: tiles it had
    not reached keep their sentinel, and the engine raises instead of returning the image."""
    import threading

    import numba
    import numpy as np

    from mogaface.bench.splat import head_scene
    from mogaface.core.splat import cancel, projection, raster, tiles
    from mogaface.core.splat.api import rasterize
    from mogaface.core.splat.function import tile_queue

    size = 1024
    (means, quats, scales, opacities, colors), viewmat, K = head_scene(200_000, size, size)
    n = means.shape[0]
    means2d, conics = (np.empty((n, k), np.float32) for k in (2, 3))
    cov2d = np.empty((n, 3), np.float64)  # the engine's types: the kernels compiled for it are reused
    depths, radii = np.empty(n, np.float32), np.empty(n, np.int32)
    projection.project_forward(means.numpy(), (quats / quats.norm(dim=1, keepdim=True)).numpy(), scales.numpy(),
                               viewmat.numpy(), K.numpy(), size, size, means2d, conics, depths, cov2d, radii)
    op, col = opacities.numpy(), colors.numpy()
    bins = tiles.bin_gaussians(means2d, cov2d, depths, op, radii, size, size)
    packed = raster.pack(bins.order, means2d, conics, cov2d, op, col, depths)
    queue = tile_queue(np.diff(bins.tile_offsets), numba.get_num_threads())

    def forward(width, height):
        rgb = np.full((height, width, 3), np.nan, np.float32)
        rest = [np.empty((height, width), np.float32) for _ in range(2)] + [np.empty((height, width), np.int32)]
        raster.forward(packed, bins.ranks, bins.tile_offsets, queue, bins.tiles_x, width, height,
                       np.zeros(3, np.float32), rgb, *rest, cancel.FLAG)
        return rgb

    assert not np.isnan(forward(size, size)).any()  # compiled, and complete without the flag
    setter = threading.Timer(0.05, lambda: cancel.FLAG.__setitem__(0, 1))
    try:
        setter.start()
        rgb = forward(size, size)  # about a second of work: the flag comes part-way
        assert np.isnan(rgb).any()
        with pytest.raises(cancel.RenderCancelled):
            rasterize(means, quats, scales, opacities, colors, viewmat, K, 64, 64)
    finally:
        setter.join()
        cancel.FLAG[0] = 0


# -- SIGTERM at any moment, refused checkpoints, a pointer that lags ---------------------------

def _handles_sigterm(pid) -> bool:
    """Whether process ``pid`` has a handler for SIGTERM yet (Linux: the SigCgt mask in /proc)."""
    try:
        with open(f"/proc/{pid}/status") as status:
            mask = next(int(line.split()[1], 16) for line in status if line.startswith("SigCgt:"))
    except (FileNotFoundError, StopIteration):
        return False
    return bool(mask >> (signal.SIGTERM - 1) & 1)


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads the signal mask from /proc")
@pytest.mark.parametrize("after", [0.0, 0.3, 1.0])
def test_sigterm_while_starting_says_so_and_exits_143(copies, tmp_path, after):
    """From the command line's first line on (``python -m mogaface`` arms SIGTERM at once), through the
    imports of torch and numba and the reading of the capture, SIGTERM ends with one line and 143."""
    process, _ = _train_process(copies, tmp_path)

    def armed_then_after():
        deadline = time.monotonic() + 120
        while not _handles_sigterm(process.pid):
            assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(after)

    err = _signalled(process, armed_then_after, signal.SIGTERM)
    assert process.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err
    assert "terminated by SIGTERM" in err or "stopped by SIGTERM" in err, err


def test_sigterm_while_training_is_said_under_quiet(copies, tmp_path):
    process, out = _train_process(copies, tmp_path)
    err = _signalled(process, lambda: _wait_for_first_step(process, out), signal.SIGTERM)
    assert process.returncode == 128 + signal.SIGTERM, err
    assert "stopped by SIGTERM at step" in err and "checkpoint written" in err


def test_a_refused_checkpoint_is_said_under_quiet_and_kept_aside(copies, capsys):
    from hostile import breakers as b

    newest = copies["run"] / "checkpoints" / "step_000003.pt"
    state = torch.load(newest, weights_only=True)
    state["extra"] = torch.zeros(100_003)
    b.torch_declaring(newest, state, 100_003, 2 ** 29, inflate=True)  # 2 GiB once inflated
    bomb = newest.read_bytes()
    code = main(["train", str(copies["capture"]), "--out", str(copies["run"]), "--resume", "--steps", "4", "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "warning: skipped a damaged checkpoint" in err and "step_000003.pt: declares" in err, err
    assert "kept the checkpoint that did not load as step_000003.pt.refused" in err
    aside = copies["run"] / "checkpoints" / "step_000003.pt.refused"
    assert aside.read_bytes() == bomb  # kept as it was
    assert load_checkpoint(newest)["step"] == 3  # the resumed run's own, from step 2
    assert [e["step"] for e in events(copies["run"]) if e["event"] == "resume"] == [2]


def test_a_checkpoint_that_would_run_code_is_refused_and_kept_aside(copies, capsys):
    import pickle

    from hostile import breakers as b

    newest = copies["run"] / "checkpoints" / "step_000003.pt"
    b.torch_declaring(newest, {"x": torch.zeros(70_000)}, 70_000, 70_000,
                      pickle_bytes=pickle.dumps({"x": b.RunsCode()}, protocol=2))
    code = main(["train", str(copies["capture"]), "--out", str(copies["run"]), "--resume", "--steps", "3", "--quiet"])
    err = capsys.readouterr().err
    assert code == 0 and "refused to load global" in err and "step_000003.pt.refused" in err, err
    assert (copies["run"] / "checkpoints" / "step_000003.pt.refused").exists()


def test_resume_takes_the_newest_complete_checkpoint_when_the_pointer_lags(copies, capsys):
    """A kill between a checkpoint and its ``latest`` pointer leaves the pointer one behind."""
    (copies["run"] / "checkpoints" / "latest").write_text("step_000002.pt\n")
    code = main(["train", str(copies["capture"]), "--out", str(copies["run"]), "--resume", "--steps", "4", "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert [e["step"] for e in events(copies["run"]) if e["event"] == "resume"] == [3]


def test_resume_without_a_pointer_takes_the_newest(copies, capsys):
    (copies["run"] / "checkpoints" / "latest").unlink()
    code = main(["train", str(copies["capture"]), "--out", str(copies["run"]), "--resume", "--steps", "4", "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert [e["step"] for e in events(copies["run"]) if e["event"] == "resume"] == [3]


def test_a_fifo_in_place_of_the_newest_checkpoint_is_skipped_without_hanging(copies, capsys):
    newest = copies["run"] / "checkpoints" / "step_000003.pt"
    newest.unlink()
    os.mkfifo(newest)
    code = main(["train", str(copies["capture"]), "--out", str(copies["run"]), "--resume", "--steps", "3", "--quiet"])
    err = capsys.readouterr().err
    assert code == 0 and "step_000003.pt: expected a regular file" in err, err
    assert stat.S_ISFIFO(os.lstat(copies["run"] / "checkpoints" / "step_000003.pt.refused").st_mode)
    assert load_checkpoint(newest)["step"] == 3


def test_blenders_auto_resume_looks_for_checkpoints_not_the_pointer(tmp_path):
    """The operator's "Auto" resumes a run whose pointer was lost, and never a finished one."""
    run = tmp_path / "run"
    assert not resumable(run)
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "latest").write_text("step_000004.pt\n")  # a pointer with no checkpoint
    assert not resumable(run)
    (run / "checkpoints" / "latest").unlink()
    (run / "checkpoints" / "step_000004.pt").write_bytes(b"")
    assert resumable(run)
    (run / "avatar.pt").write_bytes(b"")
    assert not resumable(run)


def test_a_run_is_complete_only_when_its_run_json_says_so(tmp_path):
    from mogaface.core.run.folder import is_complete

    assert not is_complete(tmp_path / "missing")
    for text, complete in (("{", False), ("[1]", False), ('{"complete": false}', False), ('{"complete": true}', True)):
        (tmp_path / "run.json").write_text(text)
        assert is_complete(tmp_path) is complete, text
