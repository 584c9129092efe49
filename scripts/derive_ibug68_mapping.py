"""Derive which MediaPipe mesh point stands for each iBUG-68 point, on the procedural head.

    python scripts/derive_ibug68_mapping.py            # derive, print the table and how consistent it is
    python scripts/derive_ibug68_mapping.py --check    # exit 1 if it differs from the stored mapping

Renders subjects 0–2 of the procedural head (the reference mesh renderer) from 15 views each,
finds the face mesh in each render with the face tracker, projects the head's own iBUG-68
embedding, and keeps for each iBUG point the mesh point nearest it on average
(:func:`mogaface.core.track.mediapipe_ibug68.derive`). Needs the face models (scripts/ensure_venv.sh).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

AZIMUTHS = (-30.0, -15.0, 0.0, 15.0, 30.0)
ELEVATIONS = (-10.0, 0.0, 10.0)
JAWS = (0.0, 0.25)  # closed and open (radians): an open mouth parts the inner lips
SUBJECTS = (0, 1, 2)
SIZE = 512
REGIONS = {"jaw": slice(0, 17), "brows": slice(17, 27), "nose": slice(27, 36), "eyes": slice(36, 48),
           "outer lips": slice(48, 60), "inner lips": slice(60, 68)}


@dataclasses.dataclass(frozen=True)
class View:
    """One render of the procedural head: the subject, the pose's name, the view's direction, the image,
    the camera and the posed mesh."""

    subject: int
    pose: str
    azimuth: float
    elevation: float
    image: np.ndarray  # (size, size, 3) uint8
    camera: object  # mogaface.core.camera.Camera
    vertices: np.ndarray  # (V, 3) the posed mesh
    faces: np.ndarray  # (F, 3)


def subject_head(subject: int):
    """The procedural head's model file arrays and its evaluator, for ``subject``."""
    import tempfile

    from mogaface.core.flame.model_file import write_model_file
    from mogaface.core.flame.numpy_model import NumpyFlame
    from mogaface.core.flame.procedural import build_head

    head = build_head(subject, 0)
    with tempfile.TemporaryDirectory() as folder:
        write_model_file(f"{folder}/head.pkl", head)
        return head, NumpyFlame.load(f"{folder}/head.pkl")


def render_poses(subjects, poses: dict, azimuths, elevations, size: int = SIZE):
    """A :class:`View` for each subject, pose (name → the evaluator's parameters) and view direction
    (the camera of :func:`~mogaface.core.data.head_preview.view_camera`, framed on the rest head), in
    that order; the reference mesh renderer on a grey background."""
    from mogaface.core.data.head_preview import view_camera
    from mogaface.core.data.mesh_render import render_mesh

    for subject in subjects:
        head, model = subject_head(subject)
        faces, texture = head["f"], head["texture"].astype(np.float32) / 255.0
        rest = model()
        for name, params in poses.items():
            vertices = model(**params)
            for azimuth in azimuths:
                for elevation in elevations:
                    camera = view_camera(rest, azimuth, elevation, size)
                    rgb, _ = render_mesh(vertices, faces, head["vt"], head["ft"], texture, camera,
                                         background=(0.5, 0.5, 0.5))
                    yield View(subject, name, azimuth, elevation, (rgb * 255 + 0.5).astype(np.uint8), camera,
                               vertices, faces)


def render_views(subjects=SUBJECTS, azimuths=AZIMUTHS, elevations=ELEVATIONS, jaws=JAWS, size: int = SIZE):
    """``(subject, azimuth, image uint8, ibug (68,2))`` for each subject and view of the procedural head."""
    from mogaface.core.flame.landmarks import procedural_embedding

    embedding = procedural_embedding()
    order = np.argsort(embedding.ibug)
    poses = {f"jaw {jaw}": {"jaw_pose": [jaw, 0.0, 0.0]} for jaw in jaws}
    for view in render_poses(subjects, poses, azimuths, elevations, size):
        ibug, _ = view.camera.project(embedding.positions(view.vertices, view.faces)[order])
        yield view.subject, view.azimuth, view.image, ibug


def ibug_mirror() -> np.ndarray:
    """Each iBUG point's mirror image, from the procedural head's embedding (its x → −x)."""
    from mogaface.core.flame.landmarks import procedural_embedding
    from mogaface.core.flame.procedural import build_head
    from mogaface.core.track.mediapipe_ibug68 import mirror_indices

    head = build_head(0, 0)
    embedding = procedural_embedding()
    points = embedding.positions(head["v_template"], head["f"])[np.argsort(embedding.ibug)]
    # the embedding puts iBUG 48 and 60 (54 and 64), the mouth's outer and inner corners, on one vertex
    return mirror_indices([(points, points * np.array([-1.0, 1.0, 1.0]))], tie_break=1e-6)


def main(argv=None) -> int:
    from mogaface.core.track import mediapipe_ibug68
    from mogaface.core.track.detect import FaceTracker

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the derived mapping differs from the stored one")
    args = parser.parse_args(argv)
    tracker = FaceTracker(track=False, mask=False)
    views, mirrored = [], []
    for subject, azimuth, image, ibug in render_views():
        result = tracker(image)
        if result.face is None:
            print(f"subject {subject}, azimuth {azimuth}: no face found", file=sys.stderr)
            continue
        views.append((ibug, result.face.landmarks))
        if subject == 0 and azimuth == 0:  # the mesh's own mirror: the frontal face, flipped left-right
            flipped = tracker(np.ascontiguousarray(image[:, ::-1])).face.landmarks[:468]
            mirrored.append((result.face.landmarks[:468], flipped * (-1, 1, 1) + (image.shape[1], 0, 0)))
    mesh_mirror = mediapipe_ibug68.mirror_indices(mirrored)
    involution = np.mean(mesh_mirror[mesh_mirror] == np.arange(len(mesh_mirror)))
    found = mediapipe_ibug68.derive(views, mesh_mirror, ibug_mirror())
    print(f"{len(views)} views; the mesh's mirror is its own inverse for {100 * involution:.1f} % of the points; "
          f"{len(set(found['mapping'].tolist()))} distinct mesh points")
    print("ibug mesh agreement error(eye-corner distances) error(px)")
    for k, (index, agreement, error, pixels) in enumerate(zip(found["mapping"], found["agreement"], found["error"],
                                                               found["error_px"])):
        print(f"{k:4d} {index:4d} {agreement:9.2f} {error:9.3f} {pixels:9.2f}")
    for name, part in REGIONS.items():
        print(f"{name:11s} agreement {found['agreement'][part].mean():.2f}, excess {found['excess'][part].mean():.3f}, "
              f"error {found['error'][part].mean():.3f} ({found['error_px'][part].mean():.1f} px)")
    print(f"mean agreement {found['agreement'].mean():.3f}, excess {found['excess'].mean():.3f}, "
          f"mean error {found['error'].mean():.3f} "
          f"({found['error_px'].mean():.2f} px; the outer eye corners are "
          f"{np.mean([np.linalg.norm(ibug[36] - ibug[45]) for ibug, _ in views]):.0f} px apart)")
    print("IBUG68_FROM_MESH = (" + ", ".join(str(int(i)) for i in found["mapping"]) + ")")
    stored = np.array(mediapipe_ibug68.IBUG68_FROM_MESH)
    differs = np.where(stored != found["mapping"])[0]
    print(f"differs from the stored mapping at iBUG {differs.tolist()}" if len(differs) else "same as the stored mapping")
    return 1 if args.check and len(differs) else 0


if __name__ == "__main__":
    sys.exit(main())
