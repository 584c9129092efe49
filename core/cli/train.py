"""``train CAPTURE --out RUN``: train an avatar on a capture (resumable; see docs/training.md)."""

from __future__ import annotations

import pathlib
import sys


def add_arguments(parser):
    from ..train.config import PRESETS

    parser.add_argument("capture", type=pathlib.Path, help="capture folder (GaussianAvatars/VHAP layout)")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="run folder (created)")
    parser.add_argument("--config", type=pathlib.Path, help="TOML settings file (see docs/training.md)")
    parser.add_argument("--preset", choices=list(PRESETS), help="a preset under the config file")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from its latest checkpoint")
    parser.add_argument("--steps", type=int, help="total optimisation steps (overrides the config)")
    parser.add_argument("--seed", type=int, help="random seed (overrides the config)")
    parser.add_argument("--threads", type=int, help="CPU threads (overrides the config)")
    parser.add_argument("--batch", type=int, help="training images per step over all ranks (overrides the config)")
    parser.add_argument("--head", type=pathlib.Path, help="head model file (default: the capture's)")
    parser.add_argument("--events", choices=["file", "stdout"], default="file",
                        help="'stdout': also print every event as a JSON line on stdout (for other programs)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _overrides(args) -> dict:
    train = {k: getattr(args, k) for k in ("steps", "seed", "threads", "batch") if getattr(args, k) is not None}
    return {"train": train} if train else {}


def _listeners(args):
    from ..progress import ProgressBar, emit_event

    listeners = []
    if args.events == "stdout":
        listeners.append(lambda e: emit_event(sys.stdout, e["event"], **{k: v for k, v in e.items() if k != "event"}))
    if not args.quiet:
        state = {"bar": None}

        def show(event):
            if event["event"] in ("start", "resume"):
                state["bar"] = ProgressBar(event["steps"], "train")
                state["bar"].update(event["step"])
            elif event["event"] == "iter" and state["bar"] is not None:
                bar = state["bar"]
                note = f"loss {event['loss']:.4f} psnr {event['psnr']:.2f} G {event['gaussians']}"
                bar.update(event["step"] - bar.done, note)
            elif event["event"] == "warning":
                print(f"\nwarning: {event['message']}", file=sys.stderr)
            elif event["event"] == "stopped":
                print(f"\nstopped by {event['signal']} at step {event['step']} (checkpoint written)",
                      file=sys.stderr)
            elif event["event"] == "done" and event.get("metrics"):
                m = event["metrics"]
                text = ", ".join(f"{k} {m[k]:.4f}" for k in ("psnr", "ssim", "lpips", "psnr_masked") if k in m)
                print(f"val ({m['frames']} frames): {text}", file=sys.stderr)

        listeners.append(show)
    return listeners


def run(args) -> int:
    from ..train.distributed import communicator_from_environment

    comm = communicator_from_environment()  # torchrun's process group, or a single process
    try:
        return _train(args, comm)
    finally:
        comm.close()


def _train(args, comm) -> int:
    from ..train import config as config_module
    from ..train.trainer import Trainer

    overrides = _overrides(args)
    if args.resume:
        if args.config is not None or args.preset is not None:
            print("error: --resume continues with the run's own config.toml; drop --config/--preset",
                  file=sys.stderr)
            return 2
        config = config_module.resolve(path=args.out / "config.toml", overrides=overrides) \
            if (args.out / "config.toml").exists() else None
    else:
        config = config_module.resolve(args.preset, args.config, overrides)
    trainer = Trainer(args.capture, args.out, config, resume=args.resume, head_file=args.head,
                      listeners=_listeners(args) if comm.is_writer else None, comm=comm)
    trainer.install_signal_handlers()
    result = trainer.run()
    if result["stopped"] is not None:
        return 128 + int(result["stopped"])
    if not args.quiet and comm.is_writer:
        print(f"wrote {args.out} (step {result['step']})", file=sys.stderr)
    return 0

