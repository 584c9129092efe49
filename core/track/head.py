"""The head model posed at a few vertices only: the fit's landmarks, the photometric stage's skin.

A clip's hundreds of frames are posed at every step of the fit, so the whole mesh is never posed:
only the vertices the points sit on, by the same linear blend skinning as
:func:`~mogaface.core.flame.lbs.linear_blend_skinning`, written for FLAME's joints.
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from ..flame.landmarks import LandmarkEmbedding
from ..flame.lbs import axis_angle_to_matrix
from ..flame.model import FlameModel

#: FLAME's kinematic tree: the root (global), the neck, then the jaw and both eyes on the neck.
FLAME_PARENTS = [-1, 0, 1, 1, 1]


class LandmarkHead(torch.nn.Module):
    """The head model posed at the vertices its landmarks sit on only: exact (the joints come from
    the regressor applied to the blend shapes once), and fast enough to pose every frame of a clip
    each step.

    The same linear blend skinning as :func:`~mogaface.core.flame.lbs.linear_blend_skinning`, written
    for FLAME's joints with the neck at rest (the fit turns the head at its root): the root and the
    neck then move a vertex alike, so the jaw and the eyes turn only the vertices they weigh on,
    about their joints, and the root's rigid motion carries the result (a vertex's weights sum to
    1, as skinning weights do). A clip's thousands of frames never build a 4×4 matrix per vertex,
    and the turns of joints that weigh on none of the points are not computed. ``dtype``: what it
    poses in (the parameters are cast to it; the fit's are float64, its posing float32)."""

    def __init__(self, model: FlameModel, embedding: LandmarkEmbedding, dtype: torch.dtype = torch.float64):
        super().__init__()
        if list(model.parents) != FLAME_PARENTS:
            raise InputError(None, "parents", f"FLAME's joints {FLAME_PARENTS} expected; found {list(model.parents)}")
        faces = model.faces.cpu().numpy()[embedding.faces]  # (L,3) vertex ids
        corners = embedding.barycentric != 0  # a corner weighing 0 is not posed
        width = int(corners.sum(1).max())
        order = np.argsort(~corners, axis=1, kind="stable")[:, :width]  # the corners that weigh, first
        rows = np.arange(len(faces))[:, None]
        vertices, corner = np.unique(faces[rows, order], return_inverse=True)
        self.corner = torch.as_tensor(corner.reshape(-1), dtype=torch.long)  # (L·width,)
        self.barycentric = torch.as_tensor(embedding.barycentric[rows, order], dtype=dtype)[..., None]
        self.vertex_ids = ids = torch.as_tensor(vertices, dtype=torch.long)  # the vertices posed
        self.dtype = d = dtype
        self.v_template = model.v_template.to(d)[ids]
        self.shapedirs = model.shapedirs.to(d)[ids]
        exprdirs = model.exprdirs.to(d)[ids].permute(2, 0, 1).reshape(model.n_expr, -1)  # (E,V·3)
        posedirs = model.posedirs.to(d).reshape(model.posedirs.shape[0], -1, 3)[:, ids]
        self.blend_dirs = torch.cat([exprdirs, posedirs.reshape(model.posedirs.shape[0], -1)])  # (E+36,V·3): one product
        weights = model.lbs_weights.to(d)[ids]  # (V,5)
        self.turning = torch.nonzero(weights[:, 2:].sum(1) > 0)[:, 0]  # the vertices the jaw or an eye moves
        self.turning_joints = 2 + torch.nonzero((weights[self.turning, 2:] > 0).any(0))[:, 0]  # and which of them
        self.turning_weights = weights[self.turning][:, self.turning_joints, None]  # (M,J,1)
        # Skin points are vertices (one corner weighing 1, in order): their posed vertices themselves.
        self.vertices_only = width == 1 and bool((self.barycentric == 1).all()) and torch.equal(
            self.corner, torch.arange(len(vertices)))
        regressor = model.J_regressor.to(d)
        self.joints_template = regressor @ model.v_template.to(d)
        self.joints_shape = torch.einsum("jv,vck->jck", regressor, model.shapedirs.to(d))
        self.joints_expr = torch.einsum("jv,vck->jck", regressor, model.exprdirs.to(d))

    def forward(self, shape, expr, rotation, jaw, translation, eyes=None, view=None) -> torch.Tensor:
        """Landmarks ``(T,L,3)`` in the world for shape ``(1,S)`` and per-frame ``(T,·)`` parameters
        (``eyes (T,6)``: FLAME's ``eyes_pose``, at rest when None); with ``view``, a rigid motion
        ``(R (3,3), t (3,))`` such as a camera's world-to-camera, in its frame (folded into the
        head's own motion: a clip's points are moved once)."""
        shape, expr, rotation, jaw, translation = (value.to(self.dtype) for value in (shape, expr, rotation, jaw, translation))
        frames, count = expr.shape[0], len(self.v_template)
        zero = torch.zeros(frames, 3, dtype=expr.dtype)
        eyes = torch.cat([zero, zero], dim=1) if eyes is None else eyes.to(self.dtype)
        rotations = axis_angle_to_matrix(torch.cat([rotation, zero, jaw, eyes], dim=1).reshape(frames, 5, 3))
        joints = (self.joints_template + torch.einsum("jck,bk->bjc", self.joints_shape, shape)
                  + torch.einsum("jck,bk->bjc", self.joints_expr, expr))  # (T,5,3)
        pose_feature = (rotations[:, 1:] - torch.eye(3, dtype=expr.dtype)).reshape(frames, -1)
        rest = self.v_template + torch.einsum("vck,bk->bvc", self.shapedirs, shape)  # (1,V,3)
        features = torch.cat([expr, pose_feature], dim=1)
        posed = torch.addmm(rest.reshape(1, -1), features, self.blend_dirs).reshape(frames, count, 3)
        # The jaw and the eyes (those that weigh on these vertices), each turning its vertices about
        # its joint (in the head's frame):
        about = posed[:, self.turning, None] - joints[:, None, self.turning_joints]  # (T,M,J,3): from each joint
        turned = torch.einsum("tjab,tmjb->tmja", rotations[:, self.turning_joints], about)
        posed = posed.index_add(1, self.turning, ((turned - about) * self.turning_weights).sum(2))
        # then the root's rigid motion (about its joint) carries the whole head:
        root, centre = rotations[:, 0], joints[:, 0]
        offset = (centre - (root @ centre[..., None])[..., 0])[:, None]  # (T,1,3)
        if view is not None:
            turn, move = (value.to(self.dtype) for value in view)
            root, offset, translation = turn @ root, offset @ turn.T, translation @ turn.T + move
        if self.vertices_only:  # each point is its vertex: the translation too is added once
            return torch.baddbmm(offset + translation[:, None, :], posed, root.transpose(1, 2))
        moved = torch.baddbmm(offset, posed, root.transpose(1, 2))
        points = moved.index_select(1, self.corner).reshape(frames, *self.barycentric.shape[:2], 3)
        return (points * self.barycentric).sum(-2) + translation[:, None, :]
