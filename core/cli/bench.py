"""``bench NAME``: run one benchmark of ``bench/`` and print its JSON report."""

from __future__ import annotations

import importlib
import json
import sys

from . import step_counts

BENCHMARKS = {
    "batch": "quality per image seen at batch 1, 2, 4 and 8 (the data-parallel batch), under each learning-rate rule",
    "cancel_latency": "SIGINT to exit while a raster kernel runs, at the largest allowed frame and in train",
    "camera_search": "choose camera refinement's settings (rates, start, gauge, rounds) on validation frames: a "
                     "training run per setting tried on a capture whose cameras are off",
    "cycles": "Cycles captures: seconds per image at 256², 512² and 802x550, hours for a whole capture, and the "
              "noise at 8-64 samples against a 1 024-sample reference",
    "converge": "time to quality at a real capture's scale (802x550, 16 cameras): the held-out camera's PSNR, SSIM "
                "and LPIPS against minutes of training, Freeze + fine-tuning and the full method",
    "distributed": "data-parallel training: ranks against threads, all-reduce volume and time per step",
    "refiner": "the multi-view refiner against test-time fitting on unseen frames: seconds per frame, PSNR gained, "
               "parameter errors; several runs (--avatar RUN,RUN,…): the table over them, by subject",
    "refiner_search": "choose the refiner's and fitting's settings on validation frames: every setting tried, scored",
    "refiner_training_search": "choose the refiner's training settings (feature grid, offsets) on validation frames: "
                               "a refiner trained per setting tried",
    "splat": "the CPU Gaussian splat engine against its torch reference",
    "splat_fuzz": "the splat engine on degenerate Gaussians and intrinsics (hangs, non-finite values)",
    "step": "one training step stage by stage (FLAME, binding, render, loss, optimiser, MoGaFace modules)",
    "track": "tracking synthetic phone clips scored against their truth: landmark reprojection, mesh, expression "
             "and camera errors, the stages' speed (--split validation to choose settings on, test to score once)",
    "track_avatar": "avatars trained on the tracked clips against ones trained on their truth, with and without the "
                    "method's corrections: novel-view PSNR at cameras the footage never saw (after bench track)",
    "track_detect": "face tracking's detection step at 720x1280: ms per frame for the detector, mesh, irises and "
                    "person mask (MediaPipe's models on ai-edge-litert)",
    "track_step": "one evaluation of the tracker's fit on a 20-s clip (600 frames): the landmarks' and skin's heads "
                  "against the library's skinning and the whole model, and the brightness agreement (ms)",
    "train": "the full training step (render, loss, backward, Adam) in steps per second",
    "viewport": "the avatar in the 3D viewport: frames per second of its render request at 256 and 512 px",
}

# the options only some benchmarks take, and which
OPTION_BENCHMARKS = {"scale": ("train", "step"),
                     "avatar": ("viewport", "refiner", "refiner_search", "refiner_training_search"),
                     "fit_steps": ("refiner",),
                     "split": ("refiner", "refiner_search", "refiner_training_search", "camera_search", "track", "track_avatar"),
                     "minutes": ("converge",), "work": ("converge", "batch", "camera_search", "track", "track_avatar"),
                     "ranks": ("converge",), "variants": ("converge",), "config": ("converge",),
                     "compare": ("converge",), "capture": ("converge",), "subjects": ("camera_search",),
                     "test_subjects": ("camera_search",), "compare_with": ("splat", "step", "train"),
                     "rounds": ("splat", "step", "train"), "together": ("track",), "photos": ("track",),
                     "steps": ("track_avatar",), "seeds": ("track_avatar",)}


def add_arguments(parser):
    from ..evaluate.protocol_names import SCORE_SPLITS

    parser.add_argument("name", choices=sorted(BENCHMARKS), help="which benchmark")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads for numba and torch")
    parser.add_argument("--quick", action="store_true", help="fewer sizes and repeats (smoke run)")
    parser.add_argument("--out", help="also write the JSON report to this file")
    parser.add_argument("--avatar", help="viewport: the avatar (run folder or avatar.pt); refiner, refiner_search: "
                                         "the run folder with refiner.pt, or several, comma-separated; "
                                         "refiner_training_search: run folders (default out/demo/run)")
    parser.add_argument("--fit-steps", type=step_counts,
                        help="refiner only: fitting lengths to time, comma-separated (default 10,30,100); the "
                             "refiner's time is also set against the length that matches its PSNR")
    parser.add_argument("--split", choices=SCORE_SPLITS,
                        help="refiner: score the test frames (default) or the validation sequence's; "
                             "refiner_search, refiner_training_search, camera_search: validation only")
    parser.add_argument("--minutes", type=float,
                        help="converge only: minutes of training time per variant (default 60)")
    parser.add_argument("--work", help="converge, batch, camera_search: folder for the capture (made once, reused) "
                                       "and runs (default out/bench_converge, out/bench_batch, "
                                       "out/bench_camera_search)")
    parser.add_argument("--capture", metavar="DIR",
                        help="converge only: train on this capture (its val split the held-out camera scored) "
                             "instead of making the synthetic one")
    parser.add_argument("--subjects", metavar="S,S",
                        help="camera_search only: search on the mean of these subjects' validation frames (each its "
                             "own noise draw; default 0)")
    parser.add_argument("--test-subjects", metavar="S,S",
                        help="camera_search only: then score today's and the chosen settings once on the test frames "
                             "of these subjects (each its own noise draw; none searched on)")
    parser.add_argument("--ranks", type=int,
                        help="converge only: train each variant on this many torchrun ranks of this machine, the "
                             "threads shared among them, one image per rank a step (square-root rule)")
    parser.add_argument("--variants", help="converge only: comma-separated subset of finetune,full_prior")
    parser.add_argument("--config", help="converge only: train the variants under this TOML settings file (a "
                                         "schedule to compare; its curve is named after the file)")
    parser.add_argument("--compare", metavar="A.json,B.json",
                        help="converge only: train nothing; set the curves of these earlier reports side by side "
                             "(one plot, a table timed to the PSNR the first one ends on)")
    parser.add_argument("--scale", choices=["small", "real"],
                        help="train, step: 'real' times 802x550 images, 16 cameras, 100k Gaussians "
                             "(train: the full method; step: both variants stage by stage)")
    parser.add_argument("--compare-with", metavar="REF",
                        help="splat, step, train: also run the benchmark of commit REF (a temporary git worktree), "
                             "alternately with this tree's in this invocation; print this/REF ratios and the load")
    parser.add_argument("--together", action="store_true", default=None,
                        help="track only: also track the split's clips as one capture (several videos) and score "
                             "each clip's frames against its truth")
    parser.add_argument("--photos", action="store_true", default=None,
                        help="track only: the split's folders of photos (12 around a still head, mixed sizes) "
                             "instead of its clips")
    parser.add_argument("--steps", type=int,
                        help="track_avatar only: training steps of each avatar (default: each preset's own; --quick 100)")
    parser.add_argument("--seeds", type=int,
                        help="track_avatar only: train each avatar with this many seeds (0, 1, ...; default 1)")
    parser.add_argument("--rounds", type=int,
                        help="with --compare-with: runs of each side, alternating which goes first (default 2)")


def run(args) -> int:
    try:
        module = importlib.import_module(f"mogaface.bench.{args.name}")
    except ModuleNotFoundError as error:
        print(f"error: benchmarks are not part of this install ({error})", file=sys.stderr)
        return 2
    for name, benchmarks in OPTION_BENCHMARKS.items():
        if getattr(args, name) is not None and args.name not in benchmarks:
            which = ", ".join(benchmarks[:-1]) + " and " + benchmarks[-1] if len(benchmarks) > 1 else benchmarks[0]
            print(f"error: --{name.replace('_', '-')} applies to the {which} benchmark{'s' if len(benchmarks) > 1 else ''} "
                  "only", file=sys.stderr)
            return 2
    if args.minutes is not None and not args.minutes > 0:
        print("error: --minutes must be positive", file=sys.stderr)
        return 2
    for name in ("ranks", "steps", "seeds"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            print(f"error: --{name} must be at least 1", file=sys.stderr)
            return 2
    if args.photos and args.together:
        print("error: --together tracks the split's videos as one capture; --photos has no videos", file=sys.stderr)
        return 2
    if args.rounds is not None and args.compare_with is None:
        print("error: --rounds applies with --compare-with only", file=sys.stderr)
        return 2
    options = {name: getattr(args, name) for name in OPTION_BENCHMARKS if getattr(args, name) is not None}
    if args.compare_with is not None:
        compare = importlib.import_module("mogaface.bench.compare")  # as every benchmark: by name, above the core
        ref = options.pop("compare_with")
        try:
            report = compare.run(args.name, ref, threads=args.threads, quick=args.quick, **options)
        except (ValueError, RuntimeError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
    else:
        report = module.run(threads=args.threads, quick=args.quick, **options)
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        from ..io.atomic import atomic_open

        with atomic_open(args.out, "w") as handle:
            handle.write(text + "\n")
        if isinstance(report.get("markdown"), str):  # a table: also as markdown beside the JSON
            import pathlib

            with atomic_open(pathlib.Path(args.out).with_suffix(".md"), "w") as handle:
                handle.write(report["markdown"] + "\n")
    return 0
