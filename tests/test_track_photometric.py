"""The photometric stage of tracking: skin points posed like landmarks, what each frame sees, and
the brightness agreement between frames (synthetic, known answers)."""

import numpy as np
import torch

from mogaface.core.flame.model import FlameModel
from mogaface.core.track.fit import start_camera
from mogaface.core.track.head import LandmarkHead
from mogaface.core.track.photometric import (
    CHOSEN,
    BrightnessAgreement,
    PhotometricSettings,
    frame_pairs,
    seen_points,
    skin_points,
    vertex_embedding,
)


def test_skin_points_are_posed_as_the_mesh_and_only_the_facing_front_is_seen(procedural_head_pkl):
    model = FlameModel.load(procedural_head_pkl, dtype=torch.float64)
    points = skin_points(model, 400, seed=0)
    eyes = model.lbs_weights[:, 3:5].sum(1).numpy() > 0.5
    assert len(points) == 400 and not eyes[points].any()  # never the eyeballs
    with torch.no_grad():
        vertices = model(rotation=torch.tensor([[0.0, 0.4, 0.0]])).numpy()[0]
    embedding = vertex_embedding(model.faces.numpy(), points)
    assert np.abs(embedding.positions(vertices, model.faces.numpy()) - vertices[points]).max() < 1e-12
    head = LandmarkHead(model, embedding)  # the pose the fit uses, each point's vertex alone posed
    posed = head(*(torch.zeros(1, n, dtype=torch.float64) for n in (model.n_shape, model.n_expr, 3, 3, 3)))
    assert len(head.v_template) == len(points)
    rest = model(rotation=torch.zeros(1, 3, dtype=torch.float64)).detach().numpy()[0, points]
    assert np.abs(posed.detach().numpy()[0] - rest).max() < 1e-9

    camera = start_camera(360, 640, 600.0)  # in front of the face (+z)
    front, back = int(np.argmax(vertices[:, 2])), int(np.argmin(vertices[:, 2]))
    chosen = np.array([front, back])
    params = {"shape": np.zeros(model.n_shape), "expr": np.zeros((1, model.n_expr)), "jaw_pose": np.zeros((1, 3)),
              "eyes_pose": np.zeros((1, 6)), "rotation": np.array([[0.0, 0.4, 0.0]]), "translation": np.zeros((1, 3))}
    seen, normals = seen_points(model, params, [camera], chosen)
    assert seen.tolist() == [[True, False]]  # the point nearest the camera, not the back of the head
    everything = seen_points(model, params, [camera], points)[0][0]
    assert 0.2 < everything.mean() < 0.6  # about the front half, less what the nose and ears hide


def test_brightness_agrees_where_the_points_follow_the_skin():
    """A texture sliding 1.5 px a frame: points that slide with it sample the same brightness in
    every frame (no loss), points held still do not, and the gradient moves them toward the skin."""
    rng = np.random.default_rng(0)
    texture = torch.nn.functional.avg_pool2d(torch.as_tensor(rng.random((1, 1, 80, 120)), dtype=torch.float32), 5, 1)
    frames, shift = 6, 1.5
    xs = torch.arange(texture.shape[-1], dtype=torch.float32)
    images = np.stack([np.stack([np.interp(xs - shift * t, xs, row) for row in texture[0, 0].numpy()])
                       for t in range(frames)]).astype(np.float32)
    settings = PhotometricSettings(gaps=(1, 3), blur_px=1.0, huber=1.0)
    start = torch.as_tensor(np.stack([rng.uniform(30, 70, 40), rng.uniform(20, 50, 40)], 1))
    follow = torch.stack([start + torch.tensor([shift * t, 0.0], dtype=torch.float64) for t in range(frames)])
    pairs = frame_pairs(np.zeros(frames), settings.gaps)
    agreement = BrightnessAgreement(images, np.ones((frames, 40), bool), settings, pairs)
    still = start.expand(frames, -1, -1).clone().requires_grad_(True)
    loss = agreement(still)
    assert float(agreement(follow)) < 0.02 * loss.item()  # what is left: resampling a resampled texture
    loss.backward()
    stepped = still.detach() - 0.5 * still.grad / still.grad.abs().max()  # half a pixel against the gradient
    assert float(agreement(stepped)) < loss.item()
    hidden = np.ones((frames, 40), bool)
    hidden[:, :20] = False  # points no frame sees do not count
    assert float(BrightnessAgreement(images, hidden, settings, pairs)(still.detach())) != loss.item()


def test_a_change_linear_in_the_skins_normal_is_removed_with_shading():
    """The second frame is the first brightened along x (a light the head turned under), the points'
    normals leaning along x as much: with ``shading`` each pair's change linear in the normal is
    removed and points on the skin agree; without it only the mean is, and they do not."""
    rng = np.random.default_rng(2)
    texture = torch.nn.functional.avg_pool2d(torch.as_tensor(rng.random((1, 1, 80, 120)), dtype=torch.float32), 5, 1)
    first = texture[0, 0].numpy()
    ramp = np.broadcast_to(0.004 * (np.arange(first.shape[1], dtype=np.float32) - 60), first.shape)  # (76,116)
    images = np.stack([first, first + ramp])
    points = np.stack([rng.uniform(20, 96, 50), rng.uniform(20, 56, 50)], 1)
    normals = np.zeros((2, 50, 3))
    normals[:, :, 0] = (points[:, 0] - 60) / 60  # the normal's x follows the point's: the change is linear in it
    normals[:, :, 2] = rng.uniform(0.5, 1.0, 50)
    pixels = torch.as_tensor(np.stack([points, points]))
    seen, pairs = np.ones((2, 50), bool), frame_pairs(np.zeros(2), (1,))
    loss = {shading: float(BrightnessAgreement(images, seen, PhotometricSettings(blur_px=1.0, huber=1.0, shading=shading),
                                               pairs, normals)(pixels)) for shading in (False, True)}
    assert loss[True] < 1e-3 * loss[False] and loss[False] > 1e-4


def test_a_video_is_paired_within_each_clip_and_photos_every_two():
    clips = np.array([0, 0, 0, 0, 1, 1, 1])
    pairs = frame_pairs(clips, (1, 3))
    assert sorted(map(tuple, pairs)) == [(0, 1), (0, 3), (1, 2), (2, 3), (4, 5), (5, 6)]  # not (3, 4), (1, 4), …
    assert sorted(map(tuple, frame_pairs(np.zeros(4), (1, 3), photos=True))) == [
        (0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    assert frame_pairs(np.zeros(1), (1,)).shape == (0, 2)
    given = PhotometricSettings(steps=5).resolved(photos=True)  # what is given is kept, the rest chosen for photos
    assert (given.steps, given.weight) == (5, CHOSEN["photos"]["weight"])
    assert PhotometricSettings().resolved(photos=False).steps == CHOSEN["video"]["steps"] != CHOSEN["photos"]["steps"]


def test_photos_of_several_sizes_are_compared_each_at_its_own_pixels():
    """A landscape and a portrait photo of one texture, moved by a known offset: on the shared
    canvas each is sampled at its own pixels, so points that follow the offset agree (no loss)
    and points held still do not."""
    rng = np.random.default_rng(1)
    texture = torch.nn.functional.avg_pool2d(torch.as_tensor(rng.random((1, 1, 120, 120)), dtype=torch.float32), 5, 1)
    texture = texture[0, 0].numpy()
    landscape, portrait = texture[10:70, 0:100], texture[0:100, 30:90]  # (60,100) and (100,60)
    moved = np.array([-30.0, 10.0])  # a landscape pixel (x, y) is the portrait's (x - 30, y + 10)
    points = np.stack([rng.uniform(40, 55, 30), rng.uniform(25, 45, 30)], 1)  # in the landscape photo
    settings = PhotometricSettings(blur_px=1.0, huber=1.0)
    agreement = BrightnessAgreement([landscape, portrait], np.ones((2, 30), bool), settings,
                                    frame_pairs(np.zeros(2), settings.gaps, photos=True))
    follow = torch.as_tensor(np.stack([points, points + moved]))
    still = torch.as_tensor(np.stack([points, points]))
    assert float(agreement(follow)) < 0.02 * float(agreement(still))
