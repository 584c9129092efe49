"""Compile every numba kernel ahead of its first use, into the user's cache.

numba compiles a kernel the first time a process calls it and caches the result per user
(:mod:`.numba_cache`). With an empty cache that is about a minute of single-core work in all
(the splat engine, the mesh renderer, SSIM and the triplane read), paid silently by the first
render or training step. :func:`compile_kernels` pays it up front, its groups in parallel
processes; later processes load the cached kernels in a fraction of a second.

Each group calls the public entry point (never a kernel directly) on tiny inputs, so the
argument types, and with them the cached specialisations, are the ones real runs look up
(tests/test_precompile.py checks that a training run then adds none).
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import time


def _splat() -> None:
    """The splat engine: projection, binning, packing, the rasteriser, forward and backward."""
    import torch

    from .splat import rasterize

    g = torch.Generator().manual_seed(0)
    n = 64
    means = (torch.rand(n, 3, generator=g) - 0.5).mul(0.2).requires_grad_()
    quats = torch.randn(n, 4, generator=g).requires_grad_()
    scales = torch.full((n, 3), 0.02).requires_grad_()
    opacities = torch.full((n,), 0.5).requires_grad_()
    colors = torch.rand(n, 3, generator=g).requires_grad_()
    viewmat = torch.eye(4)
    viewmat[2, 3] = 1.0
    K = torch.tensor([[40.0, 0, 16], [0, 40.0, 16], [0, 0, 1]])
    out = rasterize(means, quats, scales, opacities, colors, viewmat, K, 32, 32,
                    background=torch.ones(3).requires_grad_())
    (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()


def _mesh() -> None:
    """The mesh renderer of captures and previews (near-plane clipping included)."""
    import numpy as np

    from .camera import Camera
    from .data.mesh_render import render_mesh

    vertices = np.array([[-0.1, -0.1, 0.0], [0.1, -0.1, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.95]])
    faces = np.array([[0, 1, 2], [0, 1, 3], [1, 2, 3]])
    vt = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 1.0], [0.5, 0.5]])
    camera = Camera.look_at(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0), width=16, height=16, fx=20.0)
    texture = np.full((4, 4, 3), 128, np.uint8)
    render_mesh(vertices, faces, vt, faces, texture, camera, supersample=2, near=0.1)


def _training() -> None:
    """The training loss's SSIM and the texture attention's triplane read, forward and backward."""
    import torch

    from .correction.texture_attention import LatentTextureAttention
    from .train.losses import ssim

    g = torch.Generator().manual_seed(0)
    pred = torch.rand(24, 24, 3, generator=g).requires_grad_()
    ssim(pred, torch.rand(24, 24, 3, generator=g)).backward()
    attention = LatentTextureAttention(code_dim=8, plane_size=8)
    attention.sample(torch.rand(16, 3, generator=g) * 2 - 1).sum().backward()


#: name -> what it compiles; the longest first, so that two processes finish together
GROUPS = {"splat": _splat, "mesh": _mesh, "training": _training}


def compile_group(name: str) -> float:
    """Compile (or load from the cache) one group's kernels; returns the seconds it took."""
    start = time.perf_counter()
    GROUPS[name]()
    return time.perf_counter() - start


def compile_kernels(jobs: int = 2) -> dict[str, float]:
    """Every group's kernels, in ``jobs`` processes (1: in this one); seconds per group.

    Child processes are spawned (a fresh interpreter, never a fork of a process that may hold
    threads) and inherit the environment, so they cache into this process's folder.
    """
    if jobs <= 1:
        return {name: compile_group(name) for name in GROUPS}
    with concurrent.futures.ProcessPoolExecutor(
            max_workers=min(jobs, len(GROUPS)), mp_context=multiprocessing.get_context("spawn")) as pool:
        seconds = dict(zip(GROUPS, pool.map(compile_group, GROUPS)))
    return seconds
