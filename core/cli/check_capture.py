"""``check-capture DIR``: validate a capture folder and print a summary (exit 2 on a problem)."""

from __future__ import annotations


def add_arguments(parser) -> None:
    parser.add_argument("capture", metavar="DIR", help="capture folder (GaussianAvatars/VHAP layout)")
    parser.add_argument(
        "--cache-mib", type=int, default=512, help="image cache bound the reader would use, in MiB (default 512)"
    )


def run(args) -> int:
    from ..data.validate import validate_capture

    summary = validate_capture(args.capture, cache_bytes=args.cache_mib * 2**20)
    for line in summary.lines():
        print(line)
    print("ok")
    return 0
