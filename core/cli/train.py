"""``train CAPTURE --out RUN``: train an avatar on a capture (resumable; see docs/training.md)."""

from __future__ import annotations

import pathlib
import sys


def add_arguments(parser):
    from ..train.config import BATCH_RULES, CAMERA_GAUGES, PRESETS

    parser.add_argument("capture", type=pathlib.Path, help="capture folder (GaussianAvatars/VHAP layout)")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="run folder (created)")
    parser.add_argument("--config", type=pathlib.Path, help="TOML settings file (see docs/training.md)")
    parser.add_argument("--preset", choices=list(PRESETS), help="a preset under the config file")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from its latest checkpoint")
    parser.add_argument("--steps", type=int, help="total optimisation steps (overrides the config)")
    parser.add_argument("--minutes", type=_positive_minutes, metavar="M",
                        help="train for M minutes of training time, the whole schedule run through them at "
                             "whatever pace the machine makes (train.max_minutes = M, train.schedule = 'minutes'; "
                             "overrides the config)")
    parser.add_argument("--seed", type=int, help="random seed (overrides the config)")
    parser.add_argument("--threads", type=int, help="CPU threads (overrides the config)")
    parser.add_argument("--batch", type=_batch_size,
                        help="training images per step over all ranks (overrides the config); 'auto': one per rank "
                             "(torchrun's WORLD_SIZE, 1 in a single process)")
    parser.add_argument("--batch-rule", choices=BATCH_RULES,
                        help="with --batch B: read the settings (and --steps) as written for one image a step and "
                             "keep the images seen, every step count divided by B, the learning rates times sqrt(B) "
                             "('sqrt', measured: docs/training.md) or as they are ('none'); without it --batch "
                             "changes nothing else")
    parser.add_argument("--head", type=pathlib.Path, help="head model file (default: the capture's)")
    parser.add_argument("--refine-cameras", type=int, nargs="?", const=1, metavar="ROUNDS",
                        help="refine the cameras for a capture whose calibration is off; with ROUNDS > 1, in that "
                             "many rounds, each a fresh avatar (docs/training.md; overrides the config)")
    parser.add_argument("--cameras-start", metavar="FILE",
                        help="start the cameras' refinement from this cameras file (solve-cameras' output, or a "
                             "run's cameras_refined.json), or 'landmarks': solve them from the capture's landmarks "
                             "first; turns refinement on (overrides the config)")
    parser.add_argument("--camera-gauge", choices=CAMERA_GAUGES,
                        help="the rig's motion the camera refinement removes ([cameras] gauge): 'none' for a rig "
                             "whose camera centres are measured, which then hold the rig while the cameras turn "
                             "(docs/training.md; overrides the config)")
    parser.add_argument("--camera-delays", action="store_true",
                        help="learn each training camera's time offset against the tracking, for a rig whose "
                             "cameras are not triggered together (docs/training.md; overrides the config)")
    parser.add_argument("--camera-colour", action="store_true",
                        help="learn each training camera's affine colour of the rendered avatar, for a rig whose "
                             "cameras disagree in white balance or exposure (docs/training.md; overrides the "
                             "config)")
    parser.add_argument("--landmark-embedding", metavar="FILE", type=pathlib.Path,
                        help="with --cameras-start landmarks: where the landmarks lie on the head model (VHAP's "
                             "landmark_embedding_with_eyes.npy, FLAME's flame_static_embedding.pkl); default: the "
                             "procedural head's own, or such a file beside the head model")
    parser.add_argument("--events", choices=["file", "stdout"], default="file",
                        help="'stdout': also print every event as a JSON line on stdout (for other programs)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _batch_size(text: str) -> int | str:
    """An argparse type: a positive count, or ``auto`` (one image per rank)."""
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        import argparse

        raise argparse.ArgumentTypeError(f"expected a positive count or 'auto', got {text!r}")
    return value


def _per_rank_threads(threads: int, comm) -> int:
    """``threads`` for each of this machine's ranks, lowered so they do not share cores: torchrun's
    ``LOCAL_WORLD_SIZE`` ranks × threads stay within the machine's cores (threads fighting over a
    core stall the splat engine's parallel kernels)."""
    import os

    if comm.world == 1:  # one process: the threads asked for
        return threads
    local = int(os.environ.get("LOCAL_WORLD_SIZE", "1") or 1)
    cores = os.cpu_count() or 1
    return max(1, cores // local) if threads * local > cores else threads


def _positive_minutes(text: str) -> float:
    """An argparse type: a positive, finite number of minutes."""
    try:
        minutes = float(text)
    except ValueError:
        minutes = 0.0
    if not 0 < minutes < float("inf"):
        import argparse

        raise argparse.ArgumentTypeError(f"must be a positive number of minutes (got {text})")
    return minutes


def _overrides(args) -> dict:
    train = {k: getattr(args, k) for k in ("steps", "seed", "threads", "batch") if getattr(args, k) is not None}
    if args.minutes is not None:
        train.update(max_minutes=args.minutes, schedule="minutes")
    overrides = {"train": train} if train else {}
    if args.refine_cameras is not None:
        overrides["cameras"] = {"refine": True, "rounds": args.refine_cameras}
    if args.cameras_start is not None:
        from ..train.config import LANDMARKS_START

        start = args.cameras_start
        start = start if start == LANDMARKS_START else str(pathlib.Path(start).resolve())
        overrides.setdefault("cameras", {}).update(refine=True, start=start)
    if args.camera_gauge is not None:
        overrides.setdefault("cameras", {})["gauge"] = args.camera_gauge
    if args.camera_delays:
        overrides.setdefault("cameras", {})["delays"] = True
    if args.camera_colour:
        overrides.setdefault("cameras", {})["colour"] = True
    if args.landmark_embedding is not None:
        overrides.setdefault("cameras", {})["embedding"] = str(args.landmark_embedding.resolve())
    return overrides


def _listeners(args):
    from ..progress import ProgressBar, emit_event

    listeners = []
    if args.events == "stdout":
        listeners.append(lambda e: emit_event(sys.stdout, e["event"], **{k: v for k, v in e.items() if k != "event"}))
    after_bar = "" if args.quiet else "\n"

    def tell(event):  # warnings and the stop are said even under --quiet (it hides the progress bar)
        if event["event"] == "warning":
            print(f"{after_bar}warning: {event['message']}", file=sys.stderr)
        elif event["event"] == "stopped":
            print(f"{after_bar}stopped by {event['signal']} at step {event['step']} (checkpoint written)",
                  file=sys.stderr)

    listeners.append(tell)
    if not args.quiet:
        state = {"bar": None}

        def show(event):
            if event["event"] in ("start", "resume"):
                state["bar"] = ProgressBar(event["steps"], "train")
                state["bar"].update(event["step"])
            elif event["event"] == "iter" and state["bar"] is not None:
                bar = state["bar"]
                bar.total = max(int(event["steps"]), 1)  # a schedule in minutes refines its estimate
                note = f"loss {event['loss']:.4f} psnr {event['psnr']:.2f} G {event['gaussians']}"
                bar.update(event["step"] - bar.done, note)
            elif event["event"] == "done" and event.get("metrics"):
                m = event["metrics"]
                text = ", ".join(f"{k} {m[k]:.4f}" for k in ("psnr", "ssim", "lpips", "psnr_masked") if k in m)
                print(f"val ({m['frames']} frames): {text}", file=sys.stderr)

        listeners.append(show)
    return listeners


def _round_trainer(args, comm, rounds: int):
    """Builds an earlier round's trainer; its events also go to ``RUN/events.jsonl``, marked with
    the round (``stage``), so a reader of the run (Blender) follows every round."""
    from ..run.names import EVENTS_FILE
    from ..train.events import EventLog
    from ..train.trainer import Trainer

    log = EventLog(args.out / EVENTS_FILE) if comm.is_writer else None

    def trainer_for(folder, config, resume: bool, k: int):
        listeners = list(_listeners(args)) if comm.is_writer else None
        if comm.is_writer:
            def forward(event, stage=f"camera round {k}/{rounds}"):
                fields = {n: v for n, v in event.items() if n not in ("event", "time")}
                log.emit(event["event"], **fields, stage=stage)

            listeners.append(forward)
        trainer = Trainer(args.capture, folder, config, resume=resume, head_file=args.head, listeners=listeners,
                          comm=comm)
        trainer.install_signal_handlers()
        return trainer

    return trainer_for


def run(args) -> int:
    from ..train.distributed import communicator_from_environment

    comm = communicator_from_environment()  # torchrun's process group, or a single process
    try:
        return _train(args, comm)
    finally:
        comm.close()


def _train(args, comm) -> int:
    from ..io.atomic import write_text
    from ..run.names import CONFIG_FILE
    from ..train import config as config_module
    from ..train.checkpoint import has_checkpoint
    from ..train.rounds import ROUNDS_DIR, train_earlier_rounds
    from ..train.trainer import Trainer

    if args.batch == "auto":
        args.batch = comm.world
    overrides = _overrides(args)
    rounds_config = args.out / ROUNDS_DIR / CONFIG_FILE  # the whole run's, while earlier rounds train
    if args.batch_rule is not None and (args.batch is None or args.resume):
        print("error: --batch-rule goes with --batch on a new run (a resumed run's config.toml holds the schedule "
              "already divided)", file=sys.stderr)
        return 2
    if args.resume:
        if args.config is not None or args.preset is not None:
            print("error: --resume continues with the run's own config.toml; drop --config/--preset",
                  file=sys.stderr)
            return 2
        # RUN's own settings once its (last) round has a checkpoint; before, the whole run's, from which
        # the rounds derive theirs (RUN/config.toml of a last round that never saved is derived already)
        order = (args.out / CONFIG_FILE, rounds_config)
        if not has_checkpoint(args.out):
            order = order[::-1]
        saved = next((p for p in order if p.exists()), None)
        config = config_module.resolve(path=saved, overrides=overrides) if saved is not None else None
    else:
        config = config_module.resolve(args.preset, args.config, overrides)
        if args.batch_rule is not None:
            config = config_module.for_batch(config, args.batch, args.batch_rule)
    if config is not None and (threads := _per_rank_threads(config.train.threads, comm)) != config.train.threads:
        if comm.is_writer:
            print(f"note: {threads} thread(s) per rank instead of {config.train.threads}: this machine's ranks "
                  "would share cores", file=sys.stderr)
        config.train.threads = threads
    resume = args.resume
    if config is not None and config.cameras.rounds > 1 and not has_checkpoint(args.out):
        if comm.is_writer:
            rounds_config.parent.mkdir(parents=True, exist_ok=True)
            write_text(rounds_config, config_module.to_toml(config))
        stopped, config = train_earlier_rounds(args.out, config, _round_trainer(args, comm, config.cameras.rounds))
        if stopped is not None:
            return 128 + int(stopped)
        resume = False  # the last round is RUN itself, started now
    trainer = Trainer(args.capture, args.out, config, resume=resume, head_file=args.head,
                      listeners=_listeners(args) if comm.is_writer else None, comm=comm)
    trainer.install_signal_handlers()
    result = trainer.run()
    if result["stopped"] is not None:
        return 128 + int(result["stopped"])
    if not args.quiet and comm.is_writer:
        print(f"wrote {args.out} (step {result['step']})", file=sys.stderr)
    return 0

