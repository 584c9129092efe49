"""Compare the face tracker's detection step with MediaPipe's own pipeline on the same images.

    python3.11 -m venv /tmp/mpref && /tmp/mpref/bin/pip install mediapipe==0.10.14 'numpy<2' scikit-image
    .venv/bin/python scripts/compare_mediapipe_reference.py --reference-python /tmp/mpref/bin/python

MediaPipe (which pulls OpenCV and protobuf) runs only in that throwaway environment, in a child
process; nothing of the project depends on it. Images: scikit-image's astronaut (512×512) and the
tracking benchmark's portrait frame (720×1280, the astronaut enlarged). MediaPipe's legacy
solutions run in static-image mode (every image detected afresh), as the tracker with
``track=False``: ``FaceDetection`` (short range), ``FaceMesh`` without refinement (the 468-point
model the tracker runs) and with it (478 points from the attention model, whose irises the tracker
replaces with the iris model's) and ``SelfieSegmentation`` (general model). Prints the differences.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile

import numpy as np

REFERENCE = r"""
import json, sys
import numpy as np
import mediapipe as mp
out = {}
for path in sys.argv[1:]:
    image = np.load(path)
    h, w = image.shape[:2]
    found = {}
    with mp.solutions.face_detection.FaceDetection(model_selection=0) as detector:
        box = detector.process(image).detections[0].location_data.relative_bounding_box
        found["box"] = [box.xmin * w, box.ymin * h, (box.xmin + box.width) * w, (box.ymin + box.height) * h]
    for refine in (False, True):
        with mp.solutions.face_mesh.FaceMesh(static_image_mode=True, refine_landmarks=refine) as mesh:
            points = mesh.process(image).multi_face_landmarks[0].landmark
            found[f"refine_{refine}"] = [[p.x * w, p.y * h, p.z * w] for p in points]
    with mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=0) as segmenter:
        mask = segmenter.process(image).segmentation_mask
        np.save(path + ".mask.npy", mask)
    out[path] = found
print(json.dumps(out))
"""


def images() -> dict[str, np.ndarray]:
    from skimage import data

    from mogaface.bench.track_detect import test_frame

    return {"astronaut 512x512": data.astronaut(), "portrait 720x1280": test_frame()}


def main(argv=None) -> int:
    from mogaface.core.track.detect import FaceTracker

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--reference-python", default="/tmp/mpref/bin/python",
                        help="a Python with mediapipe==0.10.14 installed")
    args = parser.parse_args(argv)
    tracker = FaceTracker(track=False)
    rows = {}
    with tempfile.TemporaryDirectory() as folder:
        paths = {}
        for name, image in images().items():
            paths[name] = str(pathlib.Path(folder) / f"{len(paths)}.npy")
            np.save(paths[name], image)
        done = subprocess.run([args.reference_python, "-c", REFERENCE, *paths.values()], capture_output=True, text=True)
        if done.returncode != 0:
            print(done.stderr[-2000:], file=sys.stderr)
            return 1
        reference = json.loads(done.stdout.strip().splitlines()[-1])
        for name, image in images().items():
            ref = reference[paths[name]]
            mesh, refined = np.array(ref["refine_False"]), np.array(ref["refine_True"])
            result = tracker(image)
            ours = result.face.landmarks
            distance = lambda a, b: np.linalg.norm(a[:, :2] - b[:, :2], axis=1)  # noqa: E731
            rows[name] = {
                "box corners, mean px": float(np.abs(result.face.box - np.array(ref["box"])).mean()),
                "mesh 468 vs FaceMesh, mean px": float(distance(ours[:468], mesh).mean()),
                "mesh 468 vs FaceMesh, max px": float(distance(ours[:468], mesh).max()),
                "mesh z vs FaceMesh, mean px": float(np.abs(ours[:468, 2] - mesh[:, 2]).mean()),
                "irises vs refined FaceMesh, mean px": float(distance(ours[468:], refined[468:]).mean()),
                "irises vs refined FaceMesh, max px": float(distance(ours[468:], refined[468:]).max()),
                "iris centres vs refined FaceMesh, mean px": float(distance(ours[[468, 473]], refined[[468, 473]]).mean()),
                "mesh 468 vs refined FaceMesh, mean px": float(distance(ours[:468], refined[:468]).mean()),
                "mask, mean abs difference": float(np.abs(result.mask - np.load(paths[name] + ".mask.npy")).mean()),
                "eye distance px": float(np.linalg.norm(ours[33, :2] - ours[263, :2])),
            }
    print(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
