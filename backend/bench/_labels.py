"""Point labels that do not overlap, for the benchmark plots.

Sweeps put many runs close together (a knob that changes little lands beside its base), and
labels at one fixed offset cover each other. :func:`place` puts each label at the first of a
ring of candidate offsets, nearest first, whose text box (in display pixels, as the figure
renders it) overlaps no label placed before and no marker; a label moved away from its point
gets a thin leader line. Points are labelled in the order given, so the important ones
(the front, the presets) should come first."""

from __future__ import annotations

import math

# offsets in points: eight directions at growing distances, right-above first (the usual place)
RINGS = (6, 14, 24, 36, 50)
DIRECTIONS = ((1, 0.6), (1, -1.4), (-1, 0.6), (-1, -1.4), (0, 1.6), (0, -2.4), (1, 2), (-1, 2))


def _overlaps(a, b, pad: float = 1.0) -> bool:
    return not (a.x1 + pad <= b.x0 or b.x1 + pad <= a.x0 or a.y1 + pad <= b.y0 or b.y1 + pad <= a.y0)


def _inside(box, frame) -> bool:
    return box.x0 >= frame.x0 and box.x1 <= frame.x1 and box.y0 >= frame.y0 and box.y1 <= frame.y1


def place(ax, xs, ys, texts, colors=None, fontsize: float = 7, marker_px: float = 5.0) -> list:
    """Annotate ``(xs[i], ys[i])`` with ``texts[i]`` on ``ax`` without overlaps where a free
    place exists within the rings (else the last candidate tried); returns the annotations.
    Call once the axes' limits and scales are final."""
    from matplotlib.transforms import Bbox

    fig = ax.figure
    ax.autoscale(False)  # leader lines must not move the limits the boxes were measured in
    renderer = fig.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    centres = [ax.transData.transform((x, y)) for x, y in zip(xs, ys)]
    taken = [Bbox.from_extents(cx - marker_px, cy - marker_px, cx + marker_px, cy + marker_px) for cx, cy in centres]
    if ax.get_legend() is not None:
        taken.append(ax.get_legend().get_window_extent(renderer))
    out = []
    for i, (x, y, text) in enumerate(zip(xs, ys, texts)):
        color = colors[i] if colors else "k"
        note = ax.annotate(text, (x, y), xytext=(RINGS[0] * DIRECTIONS[0][0], RINGS[0] * DIRECTIONS[0][1]),
                           textcoords="offset points", fontsize=fontsize, color=color, va="center",
                           ha="left")
        chosen = None
        for ring in RINGS:
            for dx, dy in DIRECTIONS:
                note.set_position((ring * dx, ring * dy))
                note.set_ha("left" if dx > 0 else "right" if dx < 0 else "center")
                box = note.get_window_extent(renderer)
                if _inside(box, frame) and not any(_overlaps(box, t) for t in taken):
                    chosen = (ring, box)
                    break
            if chosen:
                break
        if chosen is None:  # no free place: keep the nearest, inside the axes where possible
            note.set_position((RINGS[0] * DIRECTIONS[0][0], RINGS[0] * DIRECTIONS[0][1]))
            note.set_ha("left")
            chosen = (RINGS[0], note.get_window_extent(renderer))
        box = chosen[1]
        cx, cy = centres[i]
        # a leader line from the marker's edge to the label's nearest edge, when the label is away
        tx = min(max(cx, box.x0), box.x1)
        ty = min(max(cy, box.y0), box.y1)
        d = math.hypot(tx - cx, ty - cy)
        if d > 2 * marker_px:
            inv = ax.transData.inverted()
            sx, sy = inv.transform((cx + (tx - cx) * marker_px / d, cy + (ty - cy) * marker_px / d))
            ex, ey = inv.transform((tx, ty))
            ax.plot([sx, ex], [sy, ey], color="0.5", lw=0.6, zorder=2)
        taken.append(box)
        out.append(note)
    return out
