"""Linear blend skinning with pose correctives (the SMPL/FLAME formulation), in torch."""

from __future__ import annotations

import torch


def axis_angle_to_matrix(rotvec: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula for ``(...,3)`` axis-angle vectors → ``(...,3,3)`` matrices.

    Written as ``I + a·[r]× + b·[r]×²`` with ``a = sin θ/θ`` and ``b = 2 sin²(θ/2)/θ²``,
    switching to their Taylor series near zero, so values and gradients stay exact at
    the rest pose (where every parameter starts) in float32 and float64 alike.
    """
    theta2 = (rotvec * rotvec).sum(-1, keepdim=True)
    small = theta2 < 1e-6
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(theta2_safe)
    a = torch.where(small, 1 - theta2 / 6 + theta2 * theta2 / 120, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24 + theta2 * theta2 / 720, 2 * torch.sin(theta / 2) ** 2 / theta2_safe)
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    skew = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*rotvec.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand_as(skew)
    return eye + a[..., None] * skew + b[..., None] * (skew @ skew)


def rigid_joint_transforms(rotations: torch.Tensor, joints: torch.Tensor, parents: list[int]) -> torch.Tensor:
    """Chain local joint rotations down the kinematic tree.

    ``rotations (B,J,3,3)``, rest ``joints (B,J,3)`` → ``(B,J,4,4)`` transforms that map a
    rest-pose point to its posed position when the point moves rigidly with joint j.
    """
    batch, n_joints = joints.shape[:2]
    relative = joints.clone()
    relative[:, 1:] = joints[:, 1:] - joints[:, parents[1:]]
    local = torch.zeros(batch, n_joints, 4, 4, dtype=joints.dtype, device=joints.device)
    local[..., :3, :3] = rotations
    local[..., :3, 3] = relative
    local[..., 3, 3] = 1
    chain = [local[:, 0]]
    for joint in range(1, n_joints):
        chain.append(chain[parents[joint]] @ local[:, joint])
    world = torch.stack(chain, dim=1)
    # Remove the rest position: T·(p − j_rest) expressed as a single 4×4.
    offset = (world[..., :3, :3] @ joints[..., None])[..., 0]
    return torch.cat(
        [torch.cat([world[..., :3, :3], (world[..., :3, 3] - offset)[..., None]], dim=-1), world[..., 3:, :]], dim=-2
    )


def linear_blend_skinning(
    rest_vertices: torch.Tensor,
    rotations: torch.Tensor,
    joints: torch.Tensor,
    parents: list[int],
    weights: torch.Tensor,
    posedirs: torch.Tensor,
) -> torch.Tensor:
    """Pose ``rest_vertices (B,V,3)`` with pose correctives then skinning.

    ``posedirs (P,V·3)`` are driven by the pose feature ``(R_j − I)`` of the non-root
    joints, as in FLAME; ``weights (V,J)`` blend the joint transforms.
    """
    batch, n_vertices = rest_vertices.shape[:2]
    eye = torch.eye(3, dtype=rotations.dtype, device=rotations.device)
    pose_feature = (rotations[:, 1:] - eye).reshape(batch, -1)
    posed = rest_vertices + (pose_feature @ posedirs).reshape(batch, n_vertices, 3)
    transforms = rigid_joint_transforms(rotations, joints, parents)
    blended = torch.einsum("vj,bjk->bvk", weights, transforms.reshape(batch, -1, 16)).reshape(batch, n_vertices, 4, 4)
    return (blended[..., :3, :3] @ posed[..., None])[..., 0] + blended[..., :3, 3]
