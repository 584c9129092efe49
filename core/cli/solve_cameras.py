"""``solve-cameras CAPTURE --out FILE``: turn the capture's training cameras to fit its 2D
landmarks (``landmark2d/``, as VHAP's tracker writes them) and write them as a cameras file
(the layout of ``RUN/cameras_refined.json``), for ``[cameras] start`` of a refining run."""

from __future__ import annotations

import pathlib


def add_arguments(parser) -> None:
    from ..train.config import CAMERA_GAUGES

    parser.add_argument("capture", type=pathlib.Path, help="capture folder with a landmark2d folder")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="cameras file to write (JSON)")
    parser.add_argument("--head", type=pathlib.Path, help="head model file (default: the capture's)")
    parser.add_argument("--embedding", type=pathlib.Path,
                        help="where the landmarks lie on the mesh: VHAP's landmark_embedding_with_eyes.npy, FLAME's "
                             "flame_static_embedding.pkl or an .npz (default: the procedural head's own)")
    parser.add_argument("--contour", action="store_true",
                        help="also use the jaw contour (iBUG 0-16); a detector puts it on the silhouette, which is "
                             "no fixed point of the mesh, so it is left out by default")
    parser.add_argument("--gauge", choices=CAMERA_GAUGES, default=CAMERA_GAUGES[0],
                        help="the rig's motion to remove, as [cameras] gauge (default %(default)s)")


def run(args) -> int:
    import numpy as np

    from ..data.camera_file import write_cameras
    from ..data.capture import Capture
    from ..data.capture_info import capture_head_file
    from ..evaluate.camera_error import camera_summary, pose_error
    from ..flame.landmarks import IBUG_COUNT, STATIC_IBUG, read_embedding
    from ..run.cameras import ScoringCameras
    from ..train.landmark_cameras import solve_cameras, training_cameras

    capture = Capture.open(args.capture)
    head = args.head if args.head is not None else capture_head_file(capture.root)
    embedding = read_embedding(args.embedding) if args.embedding is not None else None
    points = np.arange(IBUG_COUNT) if args.contour else STATIC_IBUG
    result = solve_cameras(capture, head, embedding, points=points, gauge=args.gauge)
    truth = ScoringCameras(capture).truth
    calibrated = training_cameras(capture)
    print(f"{'camera':<12} {'landmarks':>9} {'rms px':>15} {'turned °':>8}" + ("  error ° (was)" if truth else ""))
    for cid, row in result.report.items():
        line = (f"{cid:<12} {row['landmarks']:>9} {row['rms_before_px']:>6.2f} → {row['rms_after_px']:<6.2f} "
                f"{row['rotation_deg']:>8.3f}" + (f"  ({row['kept']}: kept)" if row["kept"] else ""))
        if cid in truth:
            line += f"  {pose_error(result.cameras[cid], truth[cid])[0]:.3f} ({pose_error(calibrated[cid], truth[cid])[0]:.3f})"
        print(line)
    if truth:
        was, now = camera_summary(calibrated, truth), camera_summary(result.cameras, truth)
        print("against cameras_gt.json: " + ", ".join(f"{k[:-4]} {was[k]:.3f}° → {now[k]:.3f}°" for k in
                                                      ("rotation_deg", "orbit_deg", "roll_deg", "aim_deg",
                                                       "rotation_aligned_deg")))
    write_cameras(args.out, result.cameras)
    print(f"wrote {len(result.cameras)} cameras to {args.out}; start refinement there with "
          f"[cameras] refine = true, start = \"{args.out}\"")
    return 0
