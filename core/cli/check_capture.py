"""``check-capture DIR``: validate a capture folder and print a summary (exit 2 on a problem)."""

from __future__ import annotations


def add_arguments(parser) -> None:
    parser.add_argument("capture", metavar="DIR", help="capture folder (GaussianAvatars/VHAP layout)")
    parser.add_argument(
        "--cache-mib", type=int, default=512, help="image cache bound the reader would use, in MiB (default 512)"
    )
    parser.add_argument("--full", action="store_true",
                        help="also decode every image and mask (finds truncated or corrupt files; slower)")
    parser.add_argument("--contact-sheet", metavar="PNG", help="also write every view of one timestep into this image")
    parser.add_argument("--timestep", type=int, help="timestep of the contact sheet (default: the first)")


def run(args) -> int:
    from ..data.validate import validate_capture

    summary = validate_capture(args.capture, cache_bytes=args.cache_mib * 2**20, full=args.full)
    for line in summary.lines():
        print(line)
    if args.contact_sheet:
        from ..data.capture import Capture
        from ..data.contact_sheet import contact_sheet
        from ..io.image import write_png

        write_png(args.contact_sheet, contact_sheet(Capture.open(args.capture), args.timestep))
        print(f"contact sheet: {args.contact_sheet}")
    print("ok")
    return 0
