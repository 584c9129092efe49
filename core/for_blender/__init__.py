"""Blender-free glue between the core and a Blender scene: the code the bpy layer calls, on this side
of the bpy line (nothing here imports bpy; ``operators/`` and ``mogaface_addon/`` do).

The Blender layer (``operators/``) reads and writes Blender data; everything it needs to compute
lives here, in numpy, testable without Blender: the axis, timeline and pixel-row conventions
(:mod:`.axes`), cameras both ways (:mod:`.cameras`), the head rig (:mod:`.head_rig`), tracked
parameters as keyframes (:mod:`.tracking`), the cached avatar (:mod:`.avatar`), the one render
request (:mod:`.render`), the GPU draw's buffers (:mod:`.splat_buffers`) and the posed Gaussians as
points (:mod:`.points`); and the processes Blender starts: training and refine-tracking workers
(:mod:`.worker`, :mod:`.launcher`) and the dependency installer (:mod:`.dependencies`).
"""
