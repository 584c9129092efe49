"""``train-refiner RUN``: train the multi-view refiner of per-frame parameters on a finished run
(the avatar frozen) and write ``RUN/refiner.pt``; ``eval`` and ``ablate`` then score it."""

from __future__ import annotations

import pathlib
import signal
import sys


def add_arguments(parser) -> None:
    parser.add_argument("run", type=pathlib.Path, metavar="RUN", help="run folder written by 'train'")
    parser.add_argument("--steps", type=int, default=800, help="training steps (default %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s)")
    parser.add_argument("--views", type=int, default=3, help="training views per sample (default %(default)s)")
    parser.add_argument("--crop", type=int, default=96, help="head crop size in pixels (default %(default)s)")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads (default %(default)s)")
    parser.add_argument("--distill", choices=["auto", "on", "off"], default="auto",
                        help="distil the run's fine-tuned parameters on captured views (auto: when it fine-tuned)")
    parser.add_argument("--out", type=pathlib.Path, help="where to write the refiner (default RUN/refiner.pt)")
    parser.add_argument("--events", choices=["none", "stdout"], default="none",
                        help="'stdout': print every event as a JSON line (for other programs)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    from ..progress import ProgressBar, emit_event
    from ..refiner.training import DEFAULT_SPEC, RefinerSettings, train_refiner

    settings = RefinerSettings(steps=args.steps, seed=args.seed, views=args.views, threads=args.threads,
                               distill={"auto": None, "on": True, "off": False}[args.distill],
                               spec={**DEFAULT_SPEC, "crop": args.crop})
    listeners = []
    if args.events == "stdout":
        listeners.append(lambda e: emit_event(sys.stdout, e["event"], **{k: v for k, v in e.items() if k != "event"}))
    if not args.quiet:
        bar = {}

        def show(event):
            if event["event"] == "start":
                bar["bar"] = ProgressBar(event["steps"], "train-refiner")
            elif event["event"] == "iter" and "bar" in bar:
                bar["bar"].update(event["step"] - bar["bar"].done, f"loss {event['loss']:.4f}")

        listeners.append(show)
    stop = {"signal": None}

    def request_stop(signum, _frame):
        stop["signal"] = signum

    previous = signal.signal(signal.SIGTERM, request_stop)
    try:
        result = train_refiner(args.run, settings, out=args.out, listeners=listeners,
                               should_stop=lambda: stop["signal"] is not None)
    finally:
        signal.signal(signal.SIGTERM, previous)
    if not args.quiet:
        print(f"wrote {result['path']} ({result['steps']} steps, {result['seconds']:.0f} s)", file=sys.stderr)
    return 0 if stop["signal"] is None else 128 + int(stop["signal"])
