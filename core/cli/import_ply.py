"""``import-ply FILE.ply --head HEAD.pkl --out avatar.pt``: a binding-space PLY back into an avatar file."""

from __future__ import annotations

import pathlib


def add_arguments(parser) -> None:
    parser.add_argument("ply", type=pathlib.Path, metavar="FILE.ply", help="binding-space PLY (with binding_0)")
    parser.add_argument("--head", type=pathlib.Path, required=True, help="the head model the binding refers to")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="avatar file to write (.pt)")


def run(args) -> int:
    import filecmp
    import shutil

    from ..avatar.export import import_binding_ply
    from ..errors import InputError
    from ..io.atomic import atomic_path

    avatar = import_binding_ply(args.ply, args.head)
    beside = args.out.parent / args.head.name
    if beside.exists():
        if not filecmp.cmp(beside, args.head, shallow=False):
            problem = f"a different head model is already there; {args.out} needs {args.head} beside it"
            raise InputError(beside, None, problem)
    else:
        with atomic_path(beside) as tmp:
            shutil.copyfile(args.head, tmp)
    avatar.save(args.out)
    print(f"wrote {args.out} ({len(avatar.gaussians)} Gaussians, head model {beside})")
    return 0
