"""``ablate CAPTURE --out DIR``: train and score the MoGaFace ablation ladder on one capture, N seeds.

Variants: Freeze, single-view, multi-view, multi-view + bank, multi-view + texture, full. Writes
``DIR/results.json``, ``DIR/results.md`` (every parameter source on unseen frames and the held-out
camera, mean ± std over seeds) and ``DIR/figure.png``; run folders go to ``DIR/runs/NAME/seedS`` and
are reused when complete, so an interrupted ablation continues. ``--split validation`` scores the
validation sequence instead (``results_validation.*``): choose settings there.
"""

from __future__ import annotations

import pathlib

from . import add_split_argument, step_counts


def add_arguments(parser):
    from ..workflows.ablation import LADDER

    parser.add_argument("capture", type=pathlib.Path, help="capture folder (GaussianAvatars/VHAP layout)")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="output folder (created)")
    parser.add_argument("--preset", default="mogaface-ablation",
                        help="training preset every variant starts from (default %(default)s)")
    parser.add_argument("--config", type=pathlib.Path, help="TOML settings over the preset (all variants)")
    parser.add_argument("--steps", type=int, help="training steps of every variant (overrides the preset)")
    parser.add_argument("--seed", type=int, default=0, help="first training seed (default %(default)s)")
    parser.add_argument("--seeds", type=int, default=3, help="seeds per variant: --seed, --seed+1, … (default %(default)s)")
    parser.add_argument("--fit-steps", type=step_counts, default="10,30",
                        help="step counts of the test-time fitting baseline, comma-separated (default %(default)s)")
    parser.add_argument("--threads", type=int, help="CPU threads (overrides the preset)")
    parser.add_argument("--variants", help=f"comma-separated subset of {','.join(LADDER)} (default: all)")
    parser.add_argument("--max-frames", type=int, help="score at most this many frames per protocol")
    parser.add_argument("--no-lpips", action="store_true", help="skip LPIPS")
    add_split_argument(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def run(args) -> int:
    from ..errors import InputError
    from ..workflows.ablation import LADDER, run_ablation, split_name

    variants = list(LADDER) if not args.variants else [v.strip() for v in args.variants.split(",") if v.strip()]
    for name in variants:
        if name not in LADDER:
            raise InputError(None, "--variants", f"unknown variant {name!r} (have {', '.join(LADDER)})")
    if args.seeds < 1:
        raise InputError(None, "--seeds", f"must be at least 1, got {args.seeds}")
    overrides = {"train": {k: getattr(args, k) for k in ("steps", "threads") if getattr(args, k) is not None}}
    result = run_ablation(args.capture, args.out, variants, seeds=[args.seed + i for i in range(args.seeds)],
                          preset=args.preset, config_path=args.config,
                          overrides=overrides if overrides["train"] else None, max_frames=args.max_frames,
                          lpips=not args.no_lpips, fit_steps=args.fit_steps, progress=not args.quiet,
                          split=args.split)
    written = [args.out / split_name(name, args.split) for name in ("results.json", "results.md", "figure.png")]
    print(written[1].read_text(encoding="utf-8"), end="")
    print(f"wrote {written[0]}, {written[1]} and {written[2]}")
    return 0 if result else 1
