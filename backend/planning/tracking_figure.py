"""``RUN/accuracy_time.png``: held-out PSNR against run time, with the run's levels and
stages marked (``--track-accuracy``; drawn by ``render``)."""

from __future__ import annotations

import math
from pathlib import Path

from PIL import Image, ImageDraw, ImageFont

from .. import fsio

SIZE = (560, 300)
MARGIN = {"left": 48, "right": 52, "top": 26, "bottom": 44}
PSNR_COLOUR = (31, 90, 180)
LOSS_COLOUR = (230, 130, 30)
LINE_COLOUR = (60, 60, 60)
# stage -> band colour (a stage name's prefix before ':' when the full name is not listed)
STAGE_COLOURS = {
    "init": (236, 236, 236), "resume": (236, 236, 236),
    "geometry": (218, 231, 250), "polish": (220, 243, 220),
    "remesh": (228, 228, 228), "refine": (228, 228, 228),
    "material:check": (236, 224, 248), "material": (253, 238, 204),
}
LEGEND = (("geometry", "geometry"), ("material", "material"), ("polish", "polish"),
          ("remesh", "re-mesh / refine"))
CAPTION = ("Held-out PSNR (dB, sRGB, within the masks; blue, left axis) and each level's validation loss "
           "(orange, right axis, log scale) against run time (scoring time not counted). Bands: blue geometry "
           "level, grey re-mesh or subdivision, yellow material stage, purple specular check, green polish round; dark "
           "lines mark where each level (L0, L1, ...) and polish round (P) begins.")


def stage_colour(stage: str) -> tuple[int, int, int]:
    return STAGE_COLOURS.get(stage) or STAGE_COLOURS.get(stage.split(":")[0], (245, 245, 245))


def nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """Round tick values covering [lo, hi] (about ``count`` of them)."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo] if math.isfinite(lo) else []
    raw = (hi - lo) / max(count - 1, 1)
    magnitude = 10 ** math.floor(math.log10(raw))
    step = next(m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    return [round(first + i * step, 10) for i in range(int((hi - first) / step + 1e-9) + 1)]


def _label(value: float) -> str:
    return f"{value:g}"


class _Axes:
    """Data to pixel coordinates of the plot area."""

    def __init__(self, x_range, y_range):
        self.x0, self.x1 = MARGIN["left"], SIZE[0] - MARGIN["right"]
        self.y0, self.y1 = SIZE[1] - MARGIN["bottom"], MARGIN["top"]
        self.xr, self.yr = x_range, y_range

    def x(self, value: float) -> float:
        lo, hi = self.xr
        return self.x0 + (value - lo) / (hi - lo) * (self.x1 - self.x0)

    def y(self, value: float, y_range=None) -> float:
        lo, hi = y_range or self.yr
        return self.y0 - (value - lo) / (hi - lo) * (self.y0 - self.y1)


def _range(values: list[float], pad: float) -> tuple[float, float]:
    if not values:
        return 0.0, 1.0
    lo, hi = min(values), max(values)
    span = max(hi - lo, pad)
    return lo - 0.1 * span, hi + 0.1 * span


def render(points: list[dict], marks: list[dict], title: str = "") -> Image.Image:
    """The figure as an RGB image; ``points`` carry ``seconds``,
    ``psnr`` and ``validation_loss``, ``marks`` ``seconds``, ``stage`` and ``level``.

    Drawn with numpy and Pillow, which the backend already needs (matplotlib is not among the
    packages the add-on installs). Pale bands behind the curve show the stage each stretch of
    time belongs to (``STAGE_COLOURS``), dark vertical lines the start of every geometry level
    (L0, L1, ...) and polish round (P); the blue line is the held-out PSNR (left axis, dB), the
    orange ones the validation loss of each level (right axis, log scale). ``CAPTION`` says the same in words
    for report.json.
    """
    image = Image.new("RGB", SIZE, (255, 255, 255))
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default()
    end = max([p["seconds"] for p in points] + [m["seconds"] for m in marks] + [1.0])
    minutes = end > 600
    unit = 60.0 if minutes else 1.0
    psnr = [p["psnr"] for p in points if p.get("psnr") is not None and math.isfinite(p["psnr"])]
    axes = _Axes((0.0, end / unit * 1.02), _range(psnr, 1.0))
    # stage bands, then level and polish lines
    for k, mark in enumerate(marks):
        stop = marks[k + 1]["seconds"] if k + 1 < len(marks) else end
        left, right = axes.x(mark["seconds"] / unit), axes.x(stop / unit)
        if right > left:
            draw.rectangle([left, axes.y1, right, axes.y0], fill=stage_colour(mark["stage"]))
    for mark in marks:
        if mark["stage"] in ("geometry", "polish"):
            x = axes.x(mark["seconds"] / unit)
            draw.line([x, axes.y1, x, axes.y0], fill=LINE_COLOUR, width=1)
            name = f"L{mark.get('level', '')}" if mark["stage"] == "geometry" else "P"
            draw.text((x + 2, axes.y1 + 1), name, fill=LINE_COLOUR, font=font)
    # axes and ticks
    draw.rectangle([axes.x0, axes.y1, axes.x1, axes.y0], outline=LINE_COLOUR)
    for value in nice_ticks(*axes.yr):
        y = axes.y(value)
        draw.line([axes.x0 - 3, y, axes.x0, y], fill=LINE_COLOUR)
        text = _label(value)
        draw.text((axes.x0 - 5 - draw.textlength(text, font=font), y - 6), text, fill=PSNR_COLOUR, font=font)
    for value in nice_ticks(*axes.xr, count=7):
        x = axes.x(value)
        draw.line([x, axes.y0, x, axes.y0 + 3], fill=LINE_COLOUR)
        text = _label(value)
        draw.text((x - draw.textlength(text, font=font) / 2, axes.y0 + 4), text, fill=LINE_COLOUR, font=font)
    draw.text((axes.x1 - 70, axes.y0 + 4 + 12), "run time (min)" if minutes else "run time (s)",
              fill=LINE_COLOUR, font=font)
    draw.text((4, 4), title or "held-out PSNR (dB) against run time", fill=LINE_COLOUR, font=font)
    _validation(draw, axes, points, unit, font)
    _curve(draw, [(axes.x(p["seconds"] / unit), axes.y(p["psnr"])) for p in points
                  if p.get("psnr") is not None and math.isfinite(p["psnr"])], PSNR_COLOUR, 2)
    _legend(draw, font)
    return image


def _curve(draw, xy: list[tuple[float, float]], colour, width: int) -> None:
    if len(xy) > 1:
        draw.line(xy, fill=colour, width=width, joint="curve")
    for x, y in xy:
        draw.ellipse([x - 2, y - 2, x + 2, y + 2], fill=colour)


def _validation(draw, axes: _Axes, points: list[dict], unit: float, font) -> None:
    """The validation loss on a log scale against the right axis, one line per level (each
    level computes it at its own image size)."""
    pairs = [(p["seconds"], math.log10(p["validation_loss"]), p.get("level")) for p in points
             if p.get("validation_loss") is not None and p["validation_loss"] > 0]
    if not pairs:
        return
    y_range = _range([v for _, v, _ in pairs], 0.05)
    for level in dict.fromkeys(lv for _, _, lv in pairs):
        _curve(draw, [(axes.x(t / unit), axes.y(v, y_range)) for t, v, lv in pairs if lv == level], LOSS_COLOUR, 1)
    for value in (y_range[0] + 0.1 * (y_range[1] - y_range[0]), y_range[1] - 0.1 * (y_range[1] - y_range[0])):
        y = axes.y(value, y_range)
        draw.line([axes.x1, y, axes.x1 + 3, y], fill=LINE_COLOUR)
        draw.text((axes.x1 + 5, y - 6), f"{10 ** value:.1e}", fill=LOSS_COLOUR, font=font)


def _legend(draw, font) -> None:
    x, y = MARGIN["left"], SIZE[1] - 14
    for stage, name in LEGEND:
        draw.rectangle([x, y + 1, x + 9, y + 10], fill=stage_colour(stage), outline=LINE_COLOUR)
        draw.text((x + 13, y), name, fill=LINE_COLOUR, font=font)
        x += 22 + draw.textlength(name, font=font)
    for colour, name in ((PSNR_COLOUR, "held-out PSNR"), (LOSS_COLOUR, "validation loss")):
        draw.line([x, y + 6, x + 12, y + 6], fill=colour, width=2)
        draw.text((x + 16, y), name, fill=colour, font=font)
        x += 26 + draw.textlength(name, font=font)


def write(path: str | Path, points: list[dict], marks: list[dict], title: str = "") -> None:
    """The figure as a PNG at ``path`` (atomic)."""
    image = render(points, marks, title)
    with fsio.atomic_path(path) as tmp:
        image.save(tmp, format="PNG")

