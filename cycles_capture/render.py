"""Render a job's images, moment by moment, skipping those already on disk; one progress event a
line on stdout (``{"event": "rendered", …}``) for the parent."""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

import numpy as np


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m mogaface.cycles_capture")
    parser.add_argument("job", type=pathlib.Path, help="a job folder written by make-capture --renderer cycles")
    parser.add_argument("--threads", type=int, default=0, help="render threads (0: all cores)")
    parser.add_argument("--part", default="1/1", help="K/N: render only the K-th of N shares of the job's moments "
                                                      "(every N-th moment from the K-th), one machine's share")
    args = parser.parse_args(argv)

    import bpy

    from ..core.data.camera_file import read_cameras
    from ..core.data.cycles_job import in_part, parse_part
    from ..core.progress import emit_event
    from .scene import HeadScene

    job = json.loads((args.job / "job.json").read_text())
    renders = args.job / "renders"
    renders.mkdir(exist_ok=True)
    mine = in_part(job["frames"], parse_part(args.part))
    todo = [(k, f) for k, f in enumerate(job["frames"]) if mine[k] and not (renders / f["image"]).exists()]
    if not todo:
        return 0
    with np.load(args.job / "scene.npz") as data:
        head = HeadScene(data, job, read_cameras(args.job / "cameras.json"), args.threads)
    camera_ids = list(head.cameras)
    moment = None
    for position, frame in todo:
        start = time.monotonic()
        if frame["moment"] != moment:
            moment = frame["moment"]
            with np.load(args.job / "moments" / f"{moment}.npz") as posed:
                head.pose(posed["vertices"], posed["wrinkle"])
        head.look_through(camera_ids[frame["camera"]])
        head.scene.cycles.seed = job["seed"] * 100003 + position  # a noise of its own for every image
        target = renders / frame["image"]
        partial = renders / f".{frame['image']}.partial.exr"
        head.scene.render.filepath = os.fspath(partial)
        bpy.ops.render.render(write_still=True)
        os.replace(partial, target)
        emit_event(sys.stdout, "rendered", image=frame["image"], seconds=time.monotonic() - start)
    return 0
