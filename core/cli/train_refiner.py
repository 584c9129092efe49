"""``train-refiner RUN``: train the multi-view refiner of per-frame parameters on a finished run
(the avatar frozen) and write ``RUN/refiner.pt``; ``eval`` and ``ablate`` then score it."""

from __future__ import annotations

import pathlib
import signal
import sys


def add_arguments(parser) -> None:
    parser.add_argument("run", type=pathlib.Path, metavar="RUN", help="run folder written by 'train'")
    parser.add_argument("--starts", type=int, default=100,
                        help="jittered training frames rendered in every camera (default %(default)s)")
    parser.add_argument("--offsets-per-start", type=int, default=4,
                        help="known offsets rendered per start (default %(default)s)")
    parser.add_argument("--gap-timesteps", type=int, default=40,
                        help="training timesteps whose captures measure the capture-render gap (default %(default)s)")
    parser.add_argument("--curvature-timesteps", type=int, default=4,
                        help="training timesteps at which the full-size steps' curvature is measured "
                             "(default %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s)")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads (default %(default)s)")
    parser.add_argument("--out", type=pathlib.Path, help="where to write the refiner (default RUN/refiner.pt)")
    parser.add_argument("--events", choices=["none", "stdout"], default="none",
                        help="'stdout': print every event as a JSON line (for other programs)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    from ..progress import emit_event, stage_bars
    from ..refiner.training import RefinerSettings, train_refiner

    settings = RefinerSettings(starts=args.starts, offsets_per_start=args.offsets_per_start,
                               gap_timesteps=args.gap_timesteps, curvature_timesteps=args.curvature_timesteps,
                               seed=args.seed, threads=args.threads)
    listeners = []
    if args.events == "stdout":
        listeners.append(lambda e: emit_event(sys.stdout, e["event"], **{k: v for k, v in e.items() if k != "event"}))
    if not args.quiet:
        listeners.append(stage_bars("train-refiner"))
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
        print(f"wrote {result['path']} ({result['samples_per_camera']} offsets per camera, "
              f"{result['explained']:.0%} of the renders' change explained, {result['seconds']:.0f} s)", file=sys.stderr)
    return 0 if stop["signal"] is None else 128 + int(stop["signal"])
