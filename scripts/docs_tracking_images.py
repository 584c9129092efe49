"""Write the detection images of docs/tracking.md.

    .venv/bin/python scripts/docs_tracking_images.py [--out docs/images]

``tracking_detect_astronaut.png``: scikit-image's astronaut with what the face tracker finds (the
person's outside dimmed and outlined, the detector's box, the 468 mesh points in green, the irises
in red, the iBUG-68 points in blue), the whole frame and the face enlarged three times.
``tracking_ibug68_procedural.png``: the procedural head, mouth open, with its own iBUG-68 points
(blue) and the mesh points the mapping takes for them (red).
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np


def main(argv=None) -> int:
    from PIL import Image, ImageDraw
    from skimage import data

    from mogaface.core.io.image import write_png
    from mogaface.core.track.detect import FaceTracker, draw_overlay, ibug68

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="docs/images", help="folder for the images")
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out)
    tracker = FaceTracker(track=False)

    frame = data.astronaut()
    result = tracker(frame)
    whole = draw_overlay(frame, result)
    face = draw_overlay(frame, result, crop=(150, 45, 320, 215), zoom=3)
    sheet = np.full((max(whole.shape[0], face.shape[0]), whole.shape[1] + 8 + face.shape[1], 3), 255, np.uint8)
    sheet[:whole.shape[0], :whole.shape[1]] = whole
    sheet[:face.shape[0], whole.shape[1] + 8:] = face
    write_png(out / "tracking_detect_astronaut.png", sheet)

    sys.path.insert(0, str(pathlib.Path(__file__).parent))
    from derive_ibug68_mapping import render_views

    (_, _, image, truth), = render_views(subjects=(0,), azimuths=(0.0,), elevations=(0.0,), jaws=(0.25,))
    mapped = ibug68(tracker(image).face.landmarks)
    x0, y0, x1, y1, zoom = 120, 110, 392, 400, 2
    canvas = Image.fromarray(np.repeat(np.repeat(image[y0:y1, x0:x1], zoom, 0), zoom, 1))
    draw = ImageDraw.Draw(canvas)
    for points, colour, radius in ((truth, (60, 140, 255), 3.5), (mapped, (255, 40, 40), 2.5)):
        for x, y in (points - (x0, y0)) * zoom:
            draw.ellipse((x - radius, y - radius, x + radius, y + radius), fill=colour)
    write_png(out / "tracking_ibug68_procedural.png", np.asarray(canvas))
    return 0


if __name__ == "__main__":
    sys.exit(main())
