"""Line plots for benchmark reports, drawn with PIL (no plotting library in the environment)."""

from __future__ import annotations

COLOURS = ((31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14), (23, 190, 207),
           (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34))  # tab10: ten curves told apart


def _ticks(low: float, high: float, count: int = 5) -> list[float]:
    import math

    span = max(high - low, 1e-9)
    step = 10 ** math.floor(math.log10(span / count))
    for factor in (1, 2, 5, 10):
        if span / (step * factor) <= count:
            step *= factor
            break
    first = math.ceil(low / step) * step
    return [first + i * step for i in range(int((high - first) / step + 1e-9) + 1)]


def line_plots(path, panels: list[dict], size=(420, 300)) -> None:
    """One PNG of panels side by side. A panel: ``{"title", "x_label", "series": {name: [(x, y)…]}}``;
    every panel shares the series' colours and the legend under the first."""
    from PIL import Image, ImageDraw

    from mogaface.core.io.atomic import atomic_open

    width, height = size
    left, right, top, bottom = 52, 12, 24, 40
    names = list(dict.fromkeys(name for panel in panels for name in panel["series"]))
    legend = 16 * len(names) + 8
    image = Image.new("RGB", (width * len(panels), height + legend), "white")
    draw = ImageDraw.Draw(image)
    for index, panel in enumerate(panels):
        x0 = index * width
        points = [p for series in panel["series"].values() for p in series if p[1] is not None]
        if not points:
            continue
        xs, ys = [p[0] for p in points], [p[1] for p in points]
        x_low, x_high = min(0.0, min(xs)), max(xs) or 1.0
        pad = 0.05 * max(max(ys) - min(ys), 1e-6)
        y_low, y_high = min(ys) - pad, max(ys) + pad

        def at(x, y, x0=x0, x_low=x_low, x_high=x_high, y_low=y_low, y_high=y_high):
            return (x0 + left + (x - x_low) / (x_high - x_low) * (width - left - right),
                    top + (y_high - y) / (y_high - y_low) * (height - top - bottom))

        draw.rectangle([x0 + left, top, x0 + width - right, height - bottom], outline=(0, 0, 0))
        for tick in _ticks(y_low, y_high):
            y = at(x_low, tick)[1]
            draw.line([x0 + left - 4, y, x0 + left, y], fill=(0, 0, 0))
            draw.text((x0 + 4, y - 6), f"{tick:.3g}", fill=(0, 0, 0))
        for tick in _ticks(x_low, x_high):
            x = at(tick, y_low)[0]
            draw.line([x, height - bottom, x, height - bottom + 4], fill=(0, 0, 0))
            draw.text((x - 8, height - bottom + 6), f"{tick:g}", fill=(0, 0, 0))
        draw.text((x0 + left, 6), panel["title"], fill=(0, 0, 0))
        draw.text((x0 + width // 2 - 20, height - 16), panel["x_label"], fill=(0, 0, 0))
        for name, series in panel["series"].items():
            colour = COLOURS[names.index(name) % len(COLOURS)]
            line = [at(x, y) for x, y in series if y is not None]
            if len(line) > 1:
                draw.line(line, fill=colour, width=2)
            for x, y in line:
                draw.ellipse([x - 2, y - 2, x + 2, y + 2], fill=colour)
    for row, name in enumerate(names):
        y = height + 4 + 16 * row
        draw.line([left, y + 6, left + 24, y + 6], fill=COLOURS[row % len(COLOURS)], width=3)
        draw.text((left + 30, y), name, fill=(0, 0, 0))
    with atomic_open(path, "wb") as handle:
        image.save(handle, format="PNG")
