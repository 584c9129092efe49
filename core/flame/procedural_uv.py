"""Where each part of the procedural head lies in its texture (UV atlas boxes).

The skin fills the top of the texture; eyes, mouth, lid lining and ears share the strip below.
"""

SKIN_UV_BOTTOM = 0.25  # the skin fills v in [0.25, 1]; eyes, mouth, lid lining and ears share the strip below
EYE_UV_BOXES = ((0.0, 0.0, 0.25), (0.25, 0.0, 0.25))  # (u0, v0, size): +x eye, −x eye
MOUTH_UV_BOX = (0.5, 0.0, 0.25, 0.2)  # (u0, v0, width, height)
LID_LINING_UV_BOX = (0.5, 0.2, 0.25, 0.05)  # the lining inside both eye openings
EAR_UV_BOXES = ((0.75, 0.125, 0.25), (0.75, 0.0, 0.25))  # (u0, v0, width); height is width / 2
