"""``export-ply RUN --timestep T --out FILE.ply``: the avatar as a Gaussian PLY (world or binding space)."""

from __future__ import annotations

import pathlib


def add_arguments(parser) -> None:
    parser.add_argument("run", type=pathlib.Path, metavar="RUN", help="run folder written by 'train'")
    parser.add_argument("--timestep", type=int, required=True,
                        help="timestep whose FLAME parameters pose the avatar (binding space: whose MoGaFace "
                             "texture offsets the file holds)")
    parser.add_argument("--out", type=pathlib.Path, required=True, metavar="FILE.ply", help="output PLY file")
    parser.add_argument(
        "--binding-space", action="store_true",
        help="write triangle-local Gaussians with binding_0 plus FILE.flame_param.npz (GaussianAvatars' layout) "
        "and flame_param.npz (one row per timestep of the capture, as GaussianAvatars' viewer opens it) "
        "instead of the posed world-space Gaussians",
    )
    parser.add_argument("--capture", type=pathlib.Path, help="the run's capture folder, when it has moved")


def run(args) -> int:
    from ..avatar.export import export_binding_ply, export_world_ply
    from ..evaluate.protocols import TrackedParams
    from ..run.folder import RunFolder

    run_folder = RunFolder(args.run, args.capture)
    avatar = run_folder.load_avatar()
    capture = run_folder.open_capture()
    source = TrackedParams(capture, run_folder, avatar.flame)
    params = source.params_for(args.timestep)
    if args.binding_space:
        motion = {t: source.params_for(t) for t in capture.timesteps}
        written = export_binding_ply(avatar, args.out, params, motion=motion, timestep=args.timestep)
    else:
        written = [export_world_ply(avatar, params, args.out)]
    for path in written:
        print(path)
    print(f"{len(avatar.gaussians)} Gaussians, timestep {args.timestep}")
    return 0
