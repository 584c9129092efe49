"""Blender-free glue between the core and a Blender scene.

The Blender layer (``operators/``) reads and writes Blender data; everything it needs to compute
lives here, in numpy, testable without Blender: the axis, timeline and pixel-row conventions
(:mod:`.axes`), cameras both ways (:mod:`.cameras`), the head rig (:mod:`.head_rig`), tracked
parameters as keyframes (:mod:`.tracking`), the cached avatar (:mod:`.avatar`), the one render
request (:mod:`.render`) and the posed Gaussians as points (:mod:`.points`).
"""
