"""The evaluation protocols by name: which are scored by default, and what each scores.

Plain values, no torch: the command line lists them in its ``--help``
(:mod:`.protocols` holds how they are scored).
"""

from __future__ import annotations

PROTOCOLS = ("novel_view", "self_reenactment")  # scored by default
OPTIONAL_PROTOCOLS = ("novel_view_aligned",)  # scored when asked for
ALL_PROTOCOLS = PROTOCOLS + OPTIONAL_PROTOCOLS
