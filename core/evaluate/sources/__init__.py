"""Where a frame's FLAME parameters come from: one small interface, one short class per source.

Every protocol asks a :class:`~.base.ParamSource` for the parameters of the frame it scores and
names the scored view, which no source may look at. The sources, from the weakest to the ceiling:

- :class:`~.tracked.TrackedParams`: the tracker's parameters (the run's own on training timesteps);
- :class:`~.smoothed.SmoothedParams`: the same, smoothed in time (σ chosen on training sequences);
- :class:`~.fitted.FittedParams`: test-time fitting of expression and pose against the other views;
- :class:`~.corrected.MoGaFaceParams`: the method's own, image-assisted inference;
- :class:`~.true.TrueParams`: the capture's true parameters (synthetic captures), the ceiling.

:class:`~.driven.DrivenParams` drives one subject with another's motion (cross-identity).
"""
