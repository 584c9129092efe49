"""Benchmark of the avatar in the 3D viewport: frames per second of its render request at 256² and 512².

One viewport frame is what the draw handler's render thread does: the view's camera from its
view and projection matrices, the avatar's render (colour, alpha, depth) and the pixel buffers the
draw uploads (rows flipped, depth as window depth). The reference, in the same run, is the plain
render Render Frame makes (the core's one render at the same size): their ratio is the viewport
path's own cost. The GPU upload and draw are not included (they need a window).

``gpu_path``: the CPU side of the GPU draw (posing a frame, and a view's colours, sort and packed
texture at 30k and 100k Gaussians); the GPU draw itself is timed in the real-Blender check.

The avatar: ``--avatar`` (a run folder or ``avatar.pt``; the demo's is ``out/demo/run``), else
``out/demo/run`` when present, else a stand-in: the procedural head with one opaque Gaussian per
triangle (12 620 Gaussians). The view: a 50 mm lens, the head filling about 60% of the height.
"""

from __future__ import annotations

import os
import pathlib
import platform
import statistics
import time

DEMO_RUN = pathlib.Path("out/demo/run")


def _stand_in_avatar(folder: pathlib.Path) -> pathlib.Path:
    import torch

    from mogaface.core.avatar.avatar import Avatar
    from mogaface.core.flame.model_file import write_model_file
    from mogaface.core.flame.procedural import build_head
    from mogaface.core.run.names import AVATAR_FILE

    folder.mkdir(parents=True, exist_ok=True)
    write_model_file(folder / "head.pkl", build_head(subject=0, seed=0))
    avatar = Avatar.initial(folder / "head.pkl")
    with torch.no_grad():
        avatar.gaussians.opacity_logit.fill_(4.0)
    avatar.save(folder / AVATAR_FILE)
    return folder / AVATAR_FILE


def _view_matrices(width: int, height: int):
    """A Blender-style view (world→view) and OpenGL projection looking at the head's face."""
    import numpy as np

    lens, sensor = 50.0, 36.0
    fx = lens / sensor * 2.0  # projection[0,0] for a horizontal sensor fit
    projection = np.zeros((4, 4))
    near, far = 0.01, 100.0
    projection[0, 0] = fx * (1.0 if width >= height else height / width)
    projection[1, 1] = projection[0, 0] * width / height
    projection[2, 2] = -(far + near) / (far - near)
    projection[2, 3] = -2 * far * near / (far - near)
    projection[3, 2] = -1.0
    # the face looks along Blender's -y; the camera 0.55 m in front, looking along +y
    c2w = np.array([[1.0, 0, 0, 0.0], [0, 0, -1, -0.55], [0, 1, 0, 0.02], [0, 0, 0, 1]])
    return np.linalg.inv(c2w), projection


def _median_fps(function, repeats: int) -> tuple[float, float]:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return round(1.0 / statistics.median(times), 2), round(1.0 / min(times), 2)


def run(threads: int = 2, quick: bool = False, avatar: str | None = None) -> dict:
    import numpy as np
    import torch

    from mogaface.core.avatar.avatar import render_frame
    from mogaface.core.for_blender.avatar import avatar_location, load_avatar
    from mogaface.core.for_blender.render import RenderRequest, depth_buffer_values, render, view_camera

    torch.set_num_threads(threads)
    try:
        import numba

        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    except ImportError:
        pass
    source = avatar or (str(DEMO_RUN) if DEMO_RUN.exists() else None)
    if source is None:
        import tempfile

        path, label = _stand_in_avatar(pathlib.Path(tempfile.mkdtemp(prefix="mogaface-bench-viewport-"))), "stand-in"
    else:
        path, label = avatar_location(source)[0], str(source)
    model = load_avatar(path)
    values = {"expr": np.zeros(model.flame.n_expr), "jaw_pose": np.array([0.1, 0.0, 0.0])}
    repeats = 3 if quick else 9
    results = []
    for size in ([256] if quick else [256, 512]):
        view, projection = _view_matrices(size, size)

        def viewport_frame():
            camera = view_camera(view, projection, np.eye(4), size, size)
            result = render(RenderRequest(str(path), values, camera.camera))
            np.ascontiguousarray(result.rgba[::-1])
            depth_buffer_values(result.depth[::-1] - camera.depth_offset, projection)
            return result

        warm = viewport_frame()  # numba kernels load or compile
        camera = view_camera(view, projection, np.eye(4), size, size).camera
        from mogaface.core.for_blender.render import fitted_params

        params = fitted_params(values, model)
        fps, best = _median_fps(viewport_frame, repeats)
        ref_fps, ref_best = _median_fps(lambda: render_frame(model, params, camera, (1, 1, 1)), repeats)
        results.append({"size": size, "viewport_fps": fps, "viewport_fps_best": best,
                        "render_frame_fps": ref_fps, "render_frame_fps_best": ref_best,
                        "viewport_over_render_frame_time": round(ref_fps / fps, 3),
                        "avatar_coverage": round(float((warm.alpha > 0.5).mean()), 3)})
    if len(results) == 2:
        results[1]["time_ratio_vs_256"] = round(results[0]["viewport_fps"] / results[1]["viewport_fps"], 2)
    gpu_path = _gpu_path(str(path), values, repeats, quick)
    return {
        "benchmark": "viewport",
        "avatar": label,
        "gaussians": len(model.gaussians),
        "threads": threads,
        "quick": quick,
        "load_average_1min": round(os.getloadavg()[0], 2),
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform()},
        "units": {"fps": "frames per second, from the median (and best) of repeats; one frame = the view's "
                         "camera, the avatar's render with depth, the draw's pixel buffers (no GPU upload)"},
        "note": "wall-clock on a shared machine: a 1-minute load average above the thread count means "
                "other processes competed for the cores; compare the ratios",
        "results": results,
        "gpu_path": gpu_path,
    }


def _gpu_path(path: str, values: dict, repeats: int, quick: bool) -> dict:
    """The CPU side of the GPU draw: posing a frame (uncached, then from the per-frame cache) and,
    at 30k and 100k Gaussians (the avatar's, repeated), a view's colours, sort and packed texture
    (redone whenever the view or the frame changes). The draw itself needs a window: the real-Blender
    check (tests/real_blender/ui_check.py) measures it."""
    import numpy as np

    from mogaface.core.for_blender import splat_buffers
    from mogaface.core.for_blender.render import view_camera

    def pose(jaw):
        splat_buffers._pose_cache.clear()
        return splat_buffers.posed_splats(path, {**values, "jaw_pose": np.array([jaw, 0.0, 0.0])})

    splats = pose(0.1)
    pose_fps, _ = _median_fps(lambda: pose(0.1), repeats)
    cached_fps, _ = _median_fps(lambda: splat_buffers.posed_splats(path, {**values, "jaw_pose": np.array([0.1, 0, 0])}),
                                repeats)
    view, projection = _view_matrices(512, 512)
    camera = view_camera(view, projection, np.eye(4), 512, 512).camera
    per_view = []
    for count in ([30000] if quick else [30000, 100000]):
        reps = -(-count // len(splats.opacities))
        many = splat_buffers.PosedSplats(
            np.tile(splats.means, (reps, 1))[:count], np.tile(splats.covariances, (reps, 1))[:count],
            np.tile(splats.opacities, reps)[:count],
            np.tile(splats.colors, (reps,) + (1,) * (splats.colors.ndim - 1))[:count], "bench")
        order, frame = splat_buffers.SplatOrder(), iter(range(10 ** 6))
        fps, best = _median_fps(lambda: order.update(many, camera.w2c, next(frame)), repeats)
        per_view.append({"gaussians": count, "sort_colour_pack_fps": fps, "sort_colour_pack_fps_best": best,
                         "sh_coefficients": int(splats.colors.shape[1]) if splats.colors.ndim == 3 else 1})
    return {"pose_fps_uncached": pose_fps, "pose_fps_cached": cached_fps, "gaussians": len(splats.opacities),
            "per_view": per_view,
            "note": "CPU side only: each orbit step or frame re-sorts, colours and packs; the GPU upload "
                    "and instanced draw are measured in Blender (needs a window)"}
