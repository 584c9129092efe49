"""``render RUN --timesteps 0,5,10-20 --camera cam07``: render a run's avatar to PNG (and EXR)."""

from __future__ import annotations

import pathlib


class TimestepRanges:
    """``"0,5,10-20"`` as inclusive ranges, iterated lazily (order kept, repeats dropped), so a
    range of any length costs no memory; rendering stops at the first timestep the run lacks."""

    def __init__(self, ranges: list[tuple[int, int]]):
        self.ranges = ranges

    def __iter__(self):
        for k, (low, high) in enumerate(self.ranges):
            earlier = self.ranges[:k]
            t = low
            while t <= high:
                covering = [h for lo, h in earlier if lo <= t <= h]
                if covering:
                    t = max(covering) + 1  # skip what an earlier range already gave
                    continue
                yield t
                t += 1

    def __eq__(self, other):
        return list(self) == list(other)


def parse_timesteps(text: str) -> TimestepRanges:
    """``"0,5,10-20"`` → the timesteps 0, 5, 10, 11, …, 20 (ranges inclusive)."""
    import re

    from ..errors import InputError

    ranges: list[tuple[int, int]] = []
    for part in text.split(","):
        match = re.fullmatch(r"\s*(\d{1,18})\s*(?:-\s*(\d{1,18})\s*)?", part)
        low = int(match[1]) if match else 0
        high = int(match[2]) if match and match[2] else low
        if not match or high < low:
            raise InputError(None, "--timesteps", f"expected numbers and ranges like 0,5,10-20, got {part!r}")
        ranges.append((low, high))
    return TimestepRanges(ranges)


def add_arguments(parser) -> None:
    parser.add_argument("run", type=pathlib.Path, metavar="RUN", help="run folder written by 'train'")
    parser.add_argument("--timesteps", required=True, help="timesteps to render, e.g. 0,5,10-20")
    parser.add_argument(
        "--camera", help="camera id(s) of the capture, comma-separated (default: the held-out camera, else the first)"
    )
    parser.add_argument("--out", type=pathlib.Path, metavar="DIR", help="output folder (default RUN/renders)")
    parser.add_argument("--exr", action="store_true", help="also write RGBA EXR (linear, premultiplied alpha)")
    parser.add_argument(
        "--params", type=pathlib.Path, metavar="FLAME_PARAM_DIR",
        help="pose with {t:05d}.npz files from this folder (default: the run's, else the capture's tracked ones)",
    )
    parser.add_argument("--capture", type=pathlib.Path, help="the run's capture folder, when it has moved")


def run(args) -> int:
    from ..evaluate.render import render_run

    written = render_run(
        args.run, parse_timesteps(args.timesteps), args.camera.split(",") if args.camera else None,
        out_dir=args.out, exr=args.exr, params_dir=args.params, capture=args.capture,
    )
    for path in written:
        print(path)
    return 0
