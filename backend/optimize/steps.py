"""Optimizers in NumPy: Laplacian-preconditioned vertex steps ("Large Steps", Nicolet et al.
2021; ``VertexOptimizer``) and plain Adam for material latents."""

from __future__ import annotations

import numpy as np
from cholespy import CholeskySolverD, MatrixType
from scipy.sparse import coo_matrix, identity

from ..geometry.topology import edges


def finite(*arrays) -> bool:
    """True when every value of every array is finite (the guard against NaN/Inf steps)."""
    return all(bool(np.all(np.isfinite(np.asarray(a)))) for a in arrays)


class LaplacianSystem:
    """The sparse system M = I + lambda L of a mesh, with its Cholesky factorisation."""

    def __init__(self, faces: np.ndarray, n_vertices: int, lambda_: float):
        e, _ = edges(faces)
        n = n_vertices
        rows = np.concatenate([e[:, 0], e[:, 1]])
        cols = np.concatenate([e[:, 1], e[:, 0]])
        adj = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()
        degree = np.asarray(adj.sum(1)).ravel()
        L = coo_matrix((degree, (np.arange(n), np.arange(n))), shape=(n, n)).tocsr() - adj
        self.matrix = (identity(n, format="csr") + lambda_ * L).tocoo()
        self.solver = CholeskySolverD(n, self.matrix.row.astype(np.int32), self.matrix.col.astype(np.int32),
                                      self.matrix.data.astype(np.float64), MatrixType.COO)
        self.lambda_ = lambda_

    def multiply(self, v: np.ndarray) -> np.ndarray:
        return self.matrix @ v

    def solve(self, b: np.ndarray) -> np.ndarray:
        b = np.ascontiguousarray(b, np.float64)
        x = np.zeros_like(b)
        self.solver.solve(b, x)
        return x


class VertexOptimizer:
    """Uniform Adam on u = (I + lambda L) v.

    Vertices v are optimised through u = (I + lambda L) v, L the combinatorial Laplacian: the
    gradient in u is (I + lambda L)^-1 dLoss/dv, a smoothed gradient, and a step in u moves a
    whole neighbourhood of the surface. Steps use "uniform" Adam (one second-moment scale, the
    largest, for all coordinates), so the smoothing survives the normalisation and the largest
    step in u is about the learning rate, which is set relative to the mesh's edge length.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, lambda_: float, lr: float,
                 betas: tuple[float, float] = (0.9, 0.999)):
        self.system = LaplacianSystem(faces, len(vertices), lambda_)
        self.u = self.system.multiply(np.asarray(vertices, np.float64))
        self.lr = float(lr)
        self.betas = betas
        self.reset_moments()

    def reset_moments(self) -> None:
        self.m = np.zeros_like(self.u)
        self.v = 0.0
        self.t = 0

    @property
    def vertices(self) -> np.ndarray:
        return self.system.solve(self.u)

    def set_vertices(self, vertices: np.ndarray) -> None:
        self.u = self.system.multiply(np.asarray(vertices, np.float64))

    def step(self, grad_v: np.ndarray) -> np.ndarray:
        """One step from dLoss/dv (V, 3); returns the new vertices."""
        g = self.system.solve(grad_v)
        b1, b2 = self.betas
        self.t += 1
        self.m = b1 * self.m + (1 - b1) * g
        self.v = b2 * self.v + (1 - b2) * float(np.max(g * g))  # uniform second moment
        m_hat = self.m / (1 - b1 ** self.t)
        v_hat = self.v / (1 - b2 ** self.t)
        self.u = self.u - self.lr * m_hat / (np.sqrt(v_hat) + 1e-20)
        return self.vertices


class Adam:
    """Per-coordinate Adam on a dict of flat NumPy arrays (material latents)."""

    def __init__(self, lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.lr, self.betas, self.eps = lr, betas, eps
        self.state: dict[str, tuple[np.ndarray, np.ndarray, int]] = {}

    def step(self, params: dict[str, np.ndarray], grads: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        b1, b2 = self.betas
        out = {}
        for name, x in params.items():
            g = np.asarray(grads[name], np.float64)
            m, v, t = self.state.get(name, (np.zeros_like(g), np.zeros_like(g), 0))
            t += 1
            m = b1 * m + (1 - b1) * g
            v = b2 * v + (1 - b2) * g * g
            self.state[name] = (m, v, t)
            out[name] = np.asarray(x, np.float64) - self.lr * (m / (1 - b1 ** t)) / (np.sqrt(v / (1 - b2 ** t)) + self.eps)
        return out

    def reset(self) -> None:
        self.state.clear()


def clip_outliers(grad: np.ndarray, percentile: float) -> np.ndarray:
    """Cap per-vertex gradient lengths at their ``percentile``-th percentile (0: no cap).

    Monte Carlo gradients of a path-traced loss are heavy-tailed (a few vertices under a
    highlight or at a grazing angle get most of the energy) and the Laplacian
    preconditioner would spread such spikes over whole regions. Only the top tail is
    touched: a cap relative to the median would also flatten genuine, localised signal
    (a dent in an otherwise converged surface)."""
    if not percentile:
        return grad
    n = np.linalg.norm(grad, axis=1)
    if not np.any(n > 0):
        return grad
    cap = float(np.percentile(n, percentile))
    return grad * np.minimum(1.0, cap / np.maximum(n, 1e-30))[:, None]
