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
    parser.add_argument(
        "--head", metavar="MODEL",
        help="FLAME model file the tracking was made with (default: the capture's own head model, if it has one); "
        "used to tell from the masks whether cy is measured from the bottom or the top edge",
    )


def run(args) -> int:
    from ..data.validate import validate_capture

    summary = validate_capture(args.capture, cache_bytes=args.cache_mib * 2**20, full=args.full)
    for line in summary.lines():
        print(line)
    print(_cy_line(args))
    if args.contact_sheet:
        from ..data.capture import Capture
        from ..data.contact_sheet import contact_sheet
        from ..io.image import write_png

        write_png(args.contact_sheet, contact_sheet(Capture.open(args.capture), args.timestep))
        print(f"contact sheet: {args.contact_sheet}")
    print("ok")
    return 0


def _cy_line(args) -> str:
    """Which way cy is read, and whether the masks and the tracked mesh agree."""
    import pathlib

    from ..data.capture import Capture
    from ..data.capture_info import capture_head_file
    from ..data.cy_check import check_cy
    from ..errors import InputError

    head = args.head
    if head is None:
        try:
            head = capture_head_file(pathlib.Path(args.capture))
        except InputError:
            head = None
    return check_cy(Capture.open(args.capture), head).line()
