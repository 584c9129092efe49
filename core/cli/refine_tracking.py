"""``refine-tracking RUN``: improve the tracking of every timestep of the run's capture with the
run's multi-view refiner (trained first when the run has none) and write it as ``flame_param``
files (default ``RUN/refined_tracking``); Blender's Improve Tracking runs this command."""

from __future__ import annotations

import pathlib
import signal
import sys


def add_arguments(parser) -> None:
    parser.add_argument("run", type=pathlib.Path, metavar="RUN", help="run folder written by 'train'")
    parser.add_argument("--capture", type=pathlib.Path, help="the run's capture folder, when it has moved")
    parser.add_argument("--out", type=pathlib.Path, help="output folder (default RUN/refined_tracking; replaced only "
                                                         "if this command wrote it)")
    parser.add_argument("--passes", type=int, default=1, help="refiner passes per timestep (default %(default)s)")
    parser.add_argument("--views", type=int, default=4, help="views per timestep, spread over the rig "
                                                             "(default %(default)s)")
    parser.add_argument("--fit-steps", type=int, default=0,
                        help="then this many steps of test-time fitting to all the views from the refiner's "
                             "answer, on the timesteps whose parameters training did not fit: 1-2 s a timestep; "
                             "it read the expression slightly better and the pose worse (default %(default)s: none)")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads (default %(default)s)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _say_stopped(event) -> None:
    if event["event"] == "stopped":
        print(f"\nstopped at {event['stage']} {event['step']}/{event['steps']}; nothing was replaced", file=sys.stderr)


def run(args) -> int:
    from ..progress import stage_bars
    from ..run.names import REFINE_TRACKING_EVENTS_FILE
    from ..train.events import EventLog
    from ..workflows.refine_tracking import refine_tracking

    log = EventLog(args.run / REFINE_TRACKING_EVENTS_FILE) if args.run.is_dir() else None
    listeners = [] if log is None else [lambda e: log.emit(e["event"], **{k: v for k, v in e.items() if k != "event"})]
    if not args.quiet:
        listeners += [stage_bars("refine-tracking"), _say_stopped]
    stop = {"signal": None}

    def request_stop(signum, _frame):
        stop["signal"] = signum

    previous = {s: signal.signal(s, request_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        result = refine_tracking(args.run, out=args.out, capture=args.capture, passes=args.passes, views=args.views,
                                 fit_steps=args.fit_steps, threads=args.threads, listeners=listeners,
                                 should_stop=lambda: stop["signal"] is not None)
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        if log is not None:
            log.close()
    if result["state"] != "done":
        return 128 + int(stop["signal"] or signal.SIGINT)
    if not args.quiet:
        print(f"wrote {result['timesteps']} timesteps to {', '.join(result['folders'])} "
              f"({result['seconds']:.0f} s)", file=sys.stderr)
        for line in _truth_lines(result.get("truth_errors")):
            print(line, file=sys.stderr)
    return 0


def _truth_lines(errors) -> list[str]:
    """A synthetic capture's errors against the truth (tracked, start and refined), per group of timesteps."""
    if not errors:
        return []
    lines = ["against the truth (mm; in the avatar's gauge): whole mesh, expression alone"]
    for group in errors["start"]:
        for name in [n for n in ("tracked", "start", "refined") if n in errors]:
            e = errors[name][group]
            lines.append(f"  {group:8s} {name:7s} ({e['timesteps']} timesteps): {e['vertex_mm']:.2f} "
                         f"({e['vertex_mm_gauge']:.2f}), {e['expr_vertex_mm']:.2f} ({e['expr_vertex_mm_gauge']:.2f})")
    return lines
