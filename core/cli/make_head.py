"""``make-head OUT.pkl``: the procedural default head, in the FLAME file layout."""

from __future__ import annotations

import pathlib


def add_arguments(parser):
    parser.add_argument("out", type=pathlib.Path, help="output model file (.pkl as FLAME releases it, or .npz)")
    parser.add_argument("--subject", type=int, default=0, help="identity: shape and texture (default 0)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random details (default 0)")
    parser.add_argument(
        "--chumpy",
        action="store_true",
        help="wrap shapedirs in chumpy objects like the official FLAME 2020 file "
        "(readers then need chumpy or our loader)",
    )


def run(args) -> int:
    from ..errors import ModelFileError
    from ..flame.model_file import write_model_file
    from ..flame.procedural import build_head

    if args.out.suffix not in (".pkl", ".npz"):
        raise ModelFileError(args.out, None, "expected a .pkl or .npz file name")
    model = build_head(subject=args.subject, seed=args.seed)
    write_model_file(args.out, model, chumpy_keys=("shapedirs",) if args.chumpy else ())
    n_shape, n_expr = int(model["n_shape"]), int(model["n_expr"])
    print(
        f"wrote {args.out}: {len(model['v_template'])} vertices, {len(model['f'])} triangles, "
        f"{n_shape} shape and {n_expr} expression components (subject {args.subject}, seed {args.seed})"
    )
    return 0
