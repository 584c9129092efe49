"""Cross-identity: one subject's identity with another subject's tracked motion."""

from __future__ import annotations

import numpy as np

from ...data.capture import Capture, Frame
from ...errors import InputError
from ...run.folder import IDENTITY_KEYS, MOTION_KEYS
from .base import timestep_of


class DrivenParams:
    """Subject A's identity (shape, static offset) with subject B's tracked motion (expression,
    jaw, eyes, neck, head rotation and translation) of one B timestep.

    ``n_expr`` (A's model's count) trims B's expression or pads it with zeros when the two
    were tracked with different numbers of components.
    """

    uses_images = False
    description = "cross-identity (the driver's tracked motion)"

    def __init__(self, identity: dict[str, np.ndarray], driver: Capture, n_expr: int | None = None):
        if "shape" not in identity:
            raise InputError(None, "shape", "the driven subject's identity parameters need a shape")
        self.identity = identity
        self.driver = driver
        self.n_expr = n_expr

    def params_for(self, frame: Frame | int, exclude_view: str | None = None) -> dict[str, np.ndarray]:
        motion = self.driver.flame_params(timestep_of(frame))
        params = {k: motion[k] for k in MOTION_KEYS}
        if self.n_expr is not None and len(params["expr"]) != self.n_expr:
            expr = np.zeros(self.n_expr, np.float32)
            kept = min(self.n_expr, len(params["expr"]))
            expr[:kept] = params["expr"][:kept]
            params["expr"] = expr
        params.update({k: v for k, v in self.identity.items() if k in IDENTITY_KEYS})
        return params
