"""The ground's photo-consistency: a point of the ground plane looks alike from nearby frames.

A plane induces a homography between two views (``plane_homography``: fitted to a grid of the
plane's points projected into both). Warping a neighbouring frame by it onto a frame lines up
whatever lies on the plane (its texture, the shadows cast on it) and displaces whatever stands
off it by its parallax. Per pixel, the least colour difference over a few neighbours (the
least: the object hides part of the ground from each neighbour, not the same part from all)
is small on the ground and large on an object whose colour varies along the parallax, the
ground's colour included where the ground shows through. The frames are blurred first (render
or sensor noise). A shadowed leg with the colour of the ground it stands on is told apart by
this difference where a colour model cannot."""

from __future__ import annotations

import numpy as np

from .cameras import View

# cv2 is imported inside the functions: bpy must be imported before it in one process (tests, scripts)


def plane_homography(a: View, b: View, plane: np.ndarray, centre: np.ndarray, size: float) -> np.ndarray | None:
    """The 3x3 homography from ``a``'s pixels to ``b``'s of the plane ``n.x + d = 0`` (SfM
    world), fitted on a 7x7 grid of its points within ``size`` of ``centre``'s foot; None when
    fewer than 8 of them are in front of both cameras."""
    import cv2  # see the note at the top

    n, d = np.asarray(plane[:3], np.float64), float(plane[3])
    foot = centre - (n @ centre + d) * n
    u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    s = np.linspace(-size, size, 7)
    grid = (foot + s[:, None, None] * u + s[None, :, None] * w).reshape(-1, 3)
    ua, da = a.project(grid)
    ub, db = b.project(grid)
    ok = (da > 0) & (db > 0)
    if ok.sum() < 8:
        return None
    H, _ = cv2.findHomography(ua[ok].astype(np.float32), ub[ok].astype(np.float32), 0)
    return H


def ground_difference(rgb: np.ndarray, view: View, others: list[tuple[np.ndarray, View]], plane: np.ndarray,
                      centre: np.ndarray, size: float, blur: float = 1.5) -> np.ndarray:
    """Per pixel of ``rgb`` (``view``'s frame), the least mean absolute difference (0..255)
    from the ``others`` (frame, view) warped onto it through ``plane``; inf where none sees it."""
    import cv2  # see the note at the top

    h, w = rgb.shape[:2]
    a = cv2.GaussianBlur(np.asarray(rgb, np.float32), (0, 0), blur)
    best = np.full((h, w), np.inf, np.float32)
    ones = np.ones_like(best)
    for other, v in others:
        H = plane_homography(view, v, plane, centre, size)
        if H is None:
            continue
        b = cv2.GaussianBlur(np.asarray(other, np.float32), (0, 0), blur)
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        warped = cv2.warpPerspective(b, H, (w, h), flags=flags)
        valid = cv2.warpPerspective(ones, H, (w, h), flags=flags, borderValue=0) > 0.999
        diff = np.abs(a - warped).mean(-1)
        best = np.where(valid, np.minimum(best, diff), best)
    return best
