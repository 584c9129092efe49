"""The evaluation protocols by name: which are scored by default, and on which frames.

Plain values, no torch: the command line lists them in its ``--help``
(:mod:`.protocols` holds how they are scored).
"""

from __future__ import annotations

PROTOCOLS = ("novel_view", "self_reenactment")  # scored by default
OPTIONAL_PROTOCOLS = ("novel_view_aligned", "novel_view_colour_aligned")  # scored when asked for
# The held-out camera aligned (in pose, in colour) on half its frames, the other half scored.
ALIGNED_PROTOCOLS = OPTIONAL_PROTOCOLS
ALL_PROTOCOLS = PROTOCOLS + OPTIONAL_PROTOCOLS
# Which unseen frames the protocols score: ``test``, the held-out sequence (FREE), scored once
# with settings chosen on ``validation``, the validation sequence (VAL), where only
# self-reenactment exists (the held-out camera's frames at training timesteps have no validation
# counterpart).
SCORE_SPLITS = ("test", "validation")
