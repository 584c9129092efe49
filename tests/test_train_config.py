"""Training settings: TOML round trip, presets, errors that name the file and the key."""

import dataclasses
import json

import pytest

from mogaface.core.errors import InputError
from mogaface.core.train import config as C


def test_toml_round_trip_keeps_every_setting(tmp_path):
    config = C.resolve("quick", overrides={"train": {"seed": 7}, "lr": {"scaling": 0.02}})
    path = tmp_path / "config.toml"
    path.write_text(C.to_toml(config))
    again = C.load(path)
    assert again == config
    assert again.train.seed == 7 and again.lr.scaling == 0.02 and again.train.steps == C.PRESETS["quick"]["train"]["steps"]
    text = path.read_text()
    for key, _, doc in C.documented_defaults():
        assert f"\n{key.split('.')[1]} = " in text and doc in text


def test_precedence_defaults_preset_file_flags(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text("[train]\nsteps = 77\nseed = 3\n[densify]\ngrad_threshold = 1\n")
    config = C.resolve("demo", path, {"train": {"seed": 5}})
    assert config.train.steps == 77 and config.train.seed == 5
    assert config.densify.grad_threshold == 1.0  # an integer is accepted for a number
    assert config.densify.interval == C.PRESETS["demo"]["densify"]["interval"]
    assert config.loss == C.LossSection()


@pytest.mark.parametrize("text, field, words", [
    ("[train]\nstepz = 3\n", "train.stepz", "unknown setting"),
    ("[trian]\nsteps = 3\n", "trian", "unknown section"),
    ("[train]\nsteps = 3.5\n", "train.steps", "expected an integer"),
    ("[lr]\nposition = \"fast\"\n", "lr.position", "expected a number"),
    ("[flame]\nfinetune = 1\n", "flame.finetune", "expected true or false"),
    ("[train]\nsteps = 0\n", "train.steps", "must be positive"),
    ("[train]\nbatch = 0\n", "train.batch", "must lie in [1, 256]"),
    ("[train]\nbatch = 257\n", "train.batch", "must lie in [1, 256]"),
    ("[train]\nsteps = \n", None, "not a readable TOML file"),
])
def test_bad_settings_name_the_file_and_key(tmp_path, text, field, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as error:
        C.resolve(path=path)
    assert error.value.path == str(path)
    assert error.value.field == field
    assert words in str(error.value) and str(path) in str(error.value)


def test_presets_are_valid_and_quick_is_short():
    for name in C.PRESETS:
        C.resolve(name)
    assert C.resolve("quick").train.steps < C.resolve("demo").train.steps <= C.resolve("full").train.steps
    with pytest.raises(InputError, match="unknown preset"):
        C.resolve("slow")


def test_mogaface_presets_fine_tune_flame_and_centre_the_correction():
    for name in ("mogaface", "mogaface-demo"):
        flame = C.resolve(name).flame
        assert flame.finetune
        assert (flame.expression_lr, flame.joints_lr, flame.translation_lr) == pytest.approx((1e-2, 1e-4, 1e-5))
        assert C.resolve(name).mogaface.centring_weight > 0  # the zero-mean prior of the full method
    assert not C.resolve("full").flame.finetune
    ablation = C.resolve("mogaface-ablation").flame  # each variant says whether it fine-tunes
    assert not ablation.finetune and ablation.expression_lr == C.resolve("mogaface").flame.expression_lr


def test_every_setting_is_documented():
    for section in dataclasses.fields(C.TrainConfig):
        for f in dataclasses.fields(section.type if not isinstance(section.type, str) else getattr(C, section.type)):
            assert f.metadata.get("doc")


def test_a_batch_sees_the_same_images_on_a_schedule_divided_by_it():
    one = C.resolve(overrides={"cameras": {"refine": True, "settle_at": 3000, "settle_steps": 100},
                               "eval": {"every": 500}})
    four = C.for_batch(one, 4)
    assert (four.train.batch, four.train.steps, four.densify.start, four.densify.stop) == (4, 1000, 75, 500)
    assert (four.densify.opacity_reset_interval, four.densify.sh_degree_interval) == (300, 100)
    assert (four.cameras.settle_at, four.cameras.settle_steps, four.train.checkpoint_every) == (750, 25, 125)
    assert four.eval.every == 125 and four.train.log_every == one.train.log_every  # a display rate stays
    assert four.lr.position == pytest.approx(2 * one.lr.position)  # √4
    assert four.flame.expression_lr == pytest.approx(2 * one.flame.expression_lr)
    assert four.mogaface.texture_lr == pytest.approx(2 * one.mogaface.texture_lr)
    assert four.lr.position_final_ratio == one.lr.position_final_ratio  # a ratio, not a rate
    assert one.train.batch == 1 and one.train.steps == 4000  # the original is left alone
    plain = C.for_batch(one, 4, "none")
    assert plain.lr.position == one.lr.position and plain.train.steps == 1000
    off = C.for_batch(C.resolve(overrides={"densify": {"opacity_reset_interval": 0}}), 8)
    assert off.densify.opacity_reset_interval == 0  # "never" stays never
    with pytest.raises(InputError, match="batch rule"):
        C.for_batch(one, 2, "linear")


def test_train_with_a_batch_rule_keeps_the_images_seen_and_minutes_end_the_run(tmp_path):
    from mogaface.core.cli import main
    from mogaface.core.data.capture_settings import CaptureSettings
    from mogaface.core.data.generator import make_capture

    capture = tmp_path / "capture"
    make_capture(capture, CaptureSettings(views=3, timesteps=16, size=32, supersample=1), progress=False)
    run = tmp_path / "run"
    common = ["train", str(capture), "--out", str(run), "--preset", "quick", "--steps", "8", "--threads", "1",
              "--quiet"]
    assert main([*common, "--batch-rule", "sqrt"]) == 2  # a rule needs a batch
    assert main([*common, "--batch", "2", "--batch-rule", "sqrt"]) == 0
    saved = C.load(run / "config.toml")
    quick = C.resolve("quick")
    assert (saved.train.steps, saved.train.batch) == (4, 2)
    assert saved.densify.interval == round(quick.densify.interval / 2)
    assert saved.lr.opacity == pytest.approx(quick.lr.opacity * 2 ** 0.5)
    assert json.loads((run / "run.json").read_text())["final_step"] == 4
    assert main(["train", str(capture), "--out", str(run), "--resume", "--batch", "2", "--batch-rule", "sqrt"]) == 2
    timed = tmp_path / "timed"  # --minutes: the schedule in minutes, the time ends the run
    assert main(["train", str(capture), "--out", str(timed), "--preset", "quick", "--minutes", "0.002",
                 "--threads", "1", "--quiet"]) == 0
    saved = C.load(timed / "config.toml")
    assert (saved.train.max_minutes, saved.train.schedule) == (0.002, "minutes")
    assert json.loads((timed / "run.json").read_text())["time_limited"]


def test_batch_auto_and_threads_per_rank(monkeypatch):
    import argparse

    from mogaface.core.cli.train import _batch_size, _per_rank_threads, _positive_minutes
    from mogaface.core.train.distributed import Communicator

    assert _batch_size("auto") == "auto" and _batch_size("3") == 3
    assert _positive_minutes("2.5") == 2.5
    for bad in ("0", "-1", "inf", "nan", "soon"):
        with pytest.raises(argparse.ArgumentTypeError, match="positive number of minutes"):
            _positive_minutes(bad)
    for bad in ("0", "-2", "two"):
        with pytest.raises(argparse.ArgumentTypeError, match="positive count or 'auto'"):
            _batch_size(bad)
    monkeypatch.setattr("os.cpu_count", lambda: 8)
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "4")
    assert _per_rank_threads(16, Communicator()) == 16  # one process: as asked
    assert _per_rank_threads(8, Communicator(0, 4)) == 2  # 4 ranks here share 8 cores
    assert _per_rank_threads(2, Communicator(0, 4)) == 2  # they fit already
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "16")
    assert _per_rank_threads(4, Communicator(0, 16)) == 1  # never below one


def test_ranks_left_without_an_image_are_warned_of(tmp_path):
    from mogaface.core.data.capture_settings import CaptureSettings
    from mogaface.core.data.generator import make_capture
    from mogaface.core.train.distributed import Communicator
    from mogaface.core.train.trainer import Trainer

    class TwoRanksNoPeer(Communicator):  # rank 0 of two, with the collectives of one process
        def barrier(self):
            pass

    capture = tmp_path / "capture"
    make_capture(capture, CaptureSettings(views=3, timesteps=16, size=32, supersample=1), progress=False)
    seen = []
    trainer = Trainer(capture, tmp_path / "run", C.resolve("quick"), listeners=[seen.append],
                      comm=TwoRanksNoPeer(0, 2))
    trainer.events.close()
    assert any(e["event"] == "warning" and "ranks 1 and up render nothing" in e["message"] for e in seen)
