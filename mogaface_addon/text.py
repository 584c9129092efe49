"""Labels that wrap to the panel's width instead of being cut off at the sidebar's edge."""

from __future__ import annotations

import textwrap

#: Average width of a character of Blender's UI font at 100% scale, in pixels (a little generous).
CHAR_PX = 7.0


def wrap_lines(text: str, width_px: float, ui_scale: float = 1.0) -> list[str]:
    """``text`` broken into lines that fit ``width_px`` pixels (long paths broken anywhere)."""
    chars = max(12, int(width_px / (CHAR_PX * ui_scale)) - 3)
    return textwrap.wrap(text, chars, break_long_words=True, break_on_hyphens=False) or [""]


def wrapped_label(layout, context, text: str, icon: str = "NONE") -> None:
    """Draw ``text`` as as many labels as the region's width needs (the icon on the first)."""
    region = getattr(context, "region", None)
    width = region.width if region is not None and region.width > 1 else 300
    scale = getattr(getattr(context, "preferences", None), "system", None)
    scale = getattr(scale, "ui_scale", 1.0) or 1.0
    column = layout.column(align=True)
    for index, line in enumerate(wrap_lines(text, width, scale)):
        column.label(text=line, icon=icon if index == 0 else ("BLANK1" if icon != "NONE" else "NONE"))
