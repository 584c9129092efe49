"""``bench NAME``: run one benchmark of ``bench/`` and print its JSON report."""

from __future__ import annotations

import importlib
import json
import sys

BENCHMARKS = {
    "splat": "the CPU Gaussian splat engine against its torch reference",
    "splat_fuzz": "the splat engine on degenerate Gaussians and intrinsics (hangs, non-finite values)",
    "train": "the full training step (render, loss, backward, Adam) in steps per second",
}


def add_arguments(parser):
    parser.add_argument("name", choices=sorted(BENCHMARKS), help="which benchmark")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads for numba and torch")
    parser.add_argument("--quick", action="store_true", help="fewer sizes and repeats (smoke run)")
    parser.add_argument("--out", help="also write the JSON report to this file")


def run(args) -> int:
    try:
        module = importlib.import_module(f"mogaface.bench.{args.name}")
    except ModuleNotFoundError as error:
        print(f"error: benchmarks are not part of this install ({error})", file=sys.stderr)
        return 2
    report = module.run(threads=args.threads, quick=args.quick)
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        from ..io.atomic import atomic_open

        with atomic_open(args.out, "w") as handle:
            handle.write(text + "\n")
    return 0
