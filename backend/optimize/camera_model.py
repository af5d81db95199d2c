"""The camera model of the refinement (backend.optimize.camera_fit): rotations, the pose and
intrinsic corrections, the vertex map that stands for a moved camera, its closed-form chain rule,
and the errors between two sets of cameras."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..capture.model import Camera

LIMIT_ROT = float(np.radians(5.0))  # the most a correction may turn a camera (pan, or orbit)
LIMIT_T = 0.05  # ... or dolly it, in camera distances
LIMIT_F = float(np.log(1.05))
LIMIT_PP = 0.02  # |a| (principal point offset over focal length)


# -- rotations -------------------------------------------------------------------------------------
def skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation(omega: np.ndarray) -> np.ndarray:
    """exp([omega]x) (Rodrigues)."""
    theta = float(np.linalg.norm(omega))
    k = skew(omega)
    if theta < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + np.sin(theta) / theta * k + (1 - np.cos(theta)) / theta**2 * (k @ k)


def log_rotation(r: np.ndarray) -> np.ndarray:
    """The axis-angle vector of a rotation matrix (angles below pi)."""
    cos = float(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))
    theta = float(np.arccos(cos))
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return 0.5 * w if theta < 1e-8 else theta / (2 * np.sin(theta)) * w


# -- the corrected cameras -------------------------------------------------------------------------
@dataclasses.dataclass
class Correction:
    """Every frame's pose correction and the shared intrinsic one (see the module)."""

    omega: np.ndarray  # (N, 3) pan, tilt and roll about the camera centre (rad, camera axes)
    phi: np.ndarray  # (N, 2) orbit about the object's centre, about the camera's x and y axes (rad)
    dolly: np.ndarray  # (N,) motion towards the object's centre, in camera distances
    sigma: float = 0.0  # log focal scale
    principal: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))  # (a_x, a_y)

    @classmethod
    def zero(cls, n: int) -> "Correction":
        return cls(np.zeros((n, 3)), np.zeros((n, 2)), np.zeros(n), 0.0, np.zeros(2))

    def copy(self) -> "Correction":
        return Correction(self.omega.copy(), self.phi.copy(), self.dolly.copy(), float(self.sigma),
                          self.principal.copy())

    def finite(self) -> bool:
        return bool(all(np.all(np.isfinite(a)) for a in (self.omega, self.phi, self.dolly, self.principal))
                    and np.isfinite(self.sigma))

    def clamp(self) -> None:
        for a in (self.omega, self.phi):
            a *= np.minimum(1.0, LIMIT_ROT / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12))
        self.dolly = np.clip(self.dolly, -LIMIT_T, LIMIT_T)
        self.sigma = float(np.clip(self.sigma, -LIMIT_F, LIMIT_F))
        self.principal = np.clip(self.principal, -LIMIT_PP, LIMIT_PP)

    def take_back(self, frames: np.ndarray, other: "Correction") -> None:
        """``frames`` (a boolean mask) get ``other``'s pose corrections."""
        self.omega[frames], self.phi[frames], self.dolly[frames] = other.omega[frames], other.phi[frames], other.dolly[frames]

    def to_json(self) -> dict:
        return {"omega": self.omega.tolist(), "phi": self.phi.tolist(), "dolly": self.dolly.tolist(),
                "sigma": float(self.sigma), "principal": self.principal.tolist()}

    @classmethod
    def from_json(cls, data: dict) -> "Correction":
        return cls(np.asarray(data["omega"], np.float64).reshape(-1, 3), np.asarray(data["phi"], np.float64).reshape(-1, 2),
                   np.asarray(data["dolly"], np.float64).ravel(), float(data["sigma"]),
                   np.asarray(data["principal"], np.float64).reshape(2))


def delta(omega, phi, dolly: float, focus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R_delta, t) of the pose correction Delta = [R_delta | t] (camera frame): the pan R(omega)
    and a dolly by ``dolly`` x ``focus`` (the object's centre in the camera's frame), then an orbit
    R(phi) about ``focus``: R_delta = R(phi) R(omega), t = R(phi) (dolly focus - focus) + focus."""
    r_phi = rotation(np.array([phi[0], phi[1], 0.0]))
    return r_phi @ rotation(np.asarray(omega, np.float64)), r_phi @ ((dolly - 1.0) * focus) + focus


def corrected_camera(camera: Camera, r_delta: np.ndarray, t: np.ndarray, sigma: float, principal) -> Camera:
    """``camera`` moved by [r_delta | t] (its own frame) with the intrinsic correction."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r_delta, t
    s = float(np.exp(sigma))
    return Camera(camera.width, camera.height, camera.fx * s, camera.fy * s,
                  camera.cx + float(principal[0]) * camera.fx, camera.cy + float(principal[1]) * camera.fy,
                  np.asarray(camera.camera_to_world, np.float64) @ m, dict(camera.distortion))


def vertex_map(camera: Camera, r_delta: np.ndarray, t: np.ndarray, sigma: float, principal):
    """The map p -> q = C B R^T (C^-1 p - t) (see the module) as (M (3x3), b (3,)) with q = M p + b,
    and its parts (rc, cc, r_delta, t, B) for the chain rule."""
    c2w = np.asarray(camera.camera_to_world, np.float64)
    rc, cc = c2w[:3, :3], c2w[:3, 3]
    s = float(np.exp(sigma))
    b_mat = np.array([[s, 0.0, -principal[0]], [0.0, s, principal[1]], [0.0, 0.0, 1.0]])
    m = rc @ b_mat @ r_delta.T @ rc.T
    b = cc - rc @ b_mat @ r_delta.T @ (rc.T @ cc + t)
    return m, b, (rc, cc, r_delta, t, b_mat)


def chain(grad_q: np.ndarray, points: np.ndarray, parts, sigma: float):
    """dL/d(eps, t, sigma, a) from dL/dq (V, 3) at the mesh's vertices ``points`` (V, 3), eps the
    right tangent of R_delta (R_delta exp([eps]x))."""
    rc, cc, rd, t, b_mat = parts
    x = (points - cc) @ rc  # C^-1 p (camera frame)
    y = (x - t) @ rd  # R^T (x - t), row-wise
    g_yp = grad_q @ rc  # dL/dy' (y' = B y)
    g_y = g_yp @ b_mat  # B^T g
    d_eps = np.cross(g_y, y).sum(0)  # dy/deps = [y]x
    d_t = -(g_y @ rd.T).sum(0)  # dy/dt = -R^T
    s = float(np.exp(sigma))
    d_sigma = s * float((g_yp[:, 0] * y[:, 0] + g_yp[:, 1] * y[:, 1]).sum())
    d_a = np.array([-float((g_yp[:, 0] * y[:, 2]).sum()), float((g_yp[:, 1] * y[:, 2]).sum())])
    return d_eps, d_t, d_sigma, d_a


def pose_grads(d_eps, d_t, omega, phi, dolly: float, focus: np.ndarray):
    """dL/d(omega tangent, phi, dolly) from dL/d(eps, t) (see ``delta``): R_omega's right tangent
    is eps itself; R_phi exp([eta]x) turns R_delta by R_omega^T eta and t by
    -R_phi [(dolly - 1) focus]x eta; dt/d dolly = R_phi focus."""
    r_phi = rotation(np.array([phi[0], phi[1], 0.0]))
    r_om = rotation(np.asarray(omega, np.float64))
    local = r_phi.T @ d_t
    g_eta = r_om @ d_eps + np.cross((dolly - 1.0) * focus, local)
    return d_eps, g_eta[:2], float(focus @ local)


def reprojection_px(start: Camera, refined: Camera, points: np.ndarray) -> float:
    """Mean image distance (pixels of ``start``'s size) between ``points`` (world) projected by the
    two cameras, over the points in front of both."""
    a, za = start.project(points)
    b, zb = refined.project(points)
    ok = (za > 1e-6) & (zb > 1e-6)
    return float(np.linalg.norm(a[ok] - b[ok], axis=1).mean()) if ok.any() else 0.0


def align_similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama: (s, R, t) minimising |s R src + t - dst|^2 over corresponding rows (N, 3)."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    u, d, vt = np.linalg.svd(b.T @ a / len(src))
    e = np.eye(3)
    if np.linalg.det(u @ vt) < 0:
        e[2, 2] = -1
    r = u @ e @ vt
    var = (a**2).sum() / len(src)
    s = float(np.trace(np.diag(d) @ e) / var) if var > 0 else 1.0
    return s, r, md - s * r @ ms


def pose_errors(cameras: list[Camera], truth: list[Camera], centre: np.ndarray, align: bool = True) -> dict:
    """Rotation (degrees) and translation (% of the camera's distance to ``centre``) errors of
    ``cameras`` against ``truth``, after the similarity that best aligns the centres (the gauge)."""
    src = np.array([c.centre for c in cameras])
    dst = np.array([c.centre for c in truth])
    s, r, t = align_similarity(src, dst) if align and len(cameras) >= 3 else (1.0, np.eye(3), np.zeros(3))
    rot, trans = [], []
    for c, g in zip(cameras, truth):
        rc = r @ np.asarray(c.camera_to_world)[:3, :3]
        rel = rc.T @ np.asarray(g.camera_to_world)[:3, :3]
        rot.append(float(np.degrees(np.linalg.norm(log_rotation(rel)))))
        moved = s * r @ c.centre + t
        trans.append(100.0 * float(np.linalg.norm(moved - g.centre) / np.linalg.norm(g.centre - centre)))
    return {"rotation_deg": {"mean": float(np.mean(rot)), "max": float(np.max(rot))},
            "translation_pct": {"mean": float(np.mean(trans)), "max": float(np.max(trans))}}
