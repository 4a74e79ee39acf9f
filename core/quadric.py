"""Quadric height fields in a patch frame: fitting, normals and curvature.

A patch surface is ``w = a u^2 + b uv + c v^2 + d u + e v + f`` where
``(u, v, w) = frame.T @ (p - centroid)`` are coordinates in the patch's PCA
frame (axes as columns of ``frame``, ``e3`` the plane normal, origin at the
centroid of the patch's points, metres).  Coefficients are stored as rows
``(a, b, c, d, e, f)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._fit_kernels import fit_quadrics
from .moments import TENSOR_INDEX

__all__ = ["NodeFit", "fit_nodes", "surface_normals", "surface_curvatures", "implicit_value", "turn_over"]


@dataclass(frozen=True)
class NodeFit:
    """PCA plane and quadric of a batch of nodes (M of them).

    Attributes
    ----------
    count : (M,) float64
        Points per node.
    centroid : (M, 3) float64
        Centroid relative to the node centre (metres).
    eigenvalues : (M, 3) float64
        ``lambda1 >= lambda2 >= lambda3`` (m^2).
    frame : (M, 3, 3) float64
        PCA axes as columns.
    coeffs : (M, 6) float64
        Quadric coefficients, origin at the centroid (metres).
    rmse : (M,) float64
        Root-mean-square of the fit residuals along ``e3`` (metres).
    """

    count: np.ndarray
    centroid: np.ndarray
    eigenvalues: np.ndarray
    frame: np.ndarray
    coeffs: np.ndarray
    rmse: np.ndarray

    @property
    def sigma3(self) -> np.ndarray:
        """Surface variation ``lambda3 / (lambda1 + lambda2 + lambda3)`` (paper eq. 2)."""
        return _ratio(self.eigenvalues, 2)

    @property
    def sigma2(self) -> np.ndarray:
        """``lambda2 / (lambda1 + lambda2 + lambda3)`` (paper eq. 4); small for 3D curves."""
        return _ratio(self.eigenvalues, 1)


def _ratio(eig: np.ndarray, k: int) -> np.ndarray:
    tot = eig.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(tot > 0, eig[:, k] / np.where(tot > 0, tot, 1.0), 0.0)
    return r


def fit_nodes(moments: np.ndarray, half_edge: np.ndarray, quadric: bool = True) -> NodeFit:
    """PCA plane and (optionally) least-squares quadric of every node.

    Parameters
    ----------
    moments : (M, 35) float64
        Moments about the node centres (:mod:`patchcloud.core.moments`).
    half_edge : (M,) float64
        Half the node edge (metres); used to scale the system to order one.
    quadric : bool
        When False only the PCA is computed and ``coeffs``/``rmse`` are zeros/NaN.
    """
    moments = np.ascontiguousarray(moments, dtype=np.float64)
    m = moments.shape[0]
    mean, eig, frame = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3, 3))
    coeffs, rmse = np.zeros((m, 6)), np.full(m, np.nan)
    if m:  # one compiled loop: the PCA, the normal equations (with a tiny ridge, so that a node whose points lie on a
        # line is solvable) and the solve, node by node (moments.pca and quadric_normal_equations are its reference)
        fit_quadrics(moments, np.ascontiguousarray(np.broadcast_to(half_edge, (m,)), dtype=np.float64), *TENSOR_INDEX,
                     bool(quadric), mean, eig, frame, coeffs, rmse)
    count = moments[:, 0]
    return NodeFit(count, mean, eig, frame, coeffs, rmse)


def _to_frame(points: np.ndarray, centroid: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """``frame.T @ (p - centroid)`` row by row; all arrays have N rows."""
    return np.einsum("nai,na->ni", frame, points - centroid)


def implicit_value(points, centroid, frame, coeffs) -> np.ndarray:
    """Signed value ``w - S(u, v)`` of each point in its row's patch (metres).

    Positive on the side of the frame's ``e3`` axis.  All arrays have N rows:
    points (N, 3), centroid (N, 3), frame (N, 3, 3), coeffs (N, 6).
    """
    u, v, w = _to_frame(points, centroid, frame).T
    a, b, c, d, e, f = coeffs.T
    return w - (a * u * u + b * u * v + c * v * v + d * u + e * v + f)


def surface_normals(points, centroid, frame, coeffs) -> np.ndarray:
    """Unit normal of each row's quadric at the point's projection along ``e3``.

    The normal has a positive component along the frame's ``e3`` axis.

    Returns
    -------
    (N, 3) float64
    """
    u, v, _ = _to_frame(points, centroid, frame).T
    a, b, c, d, e, _ = coeffs.T
    su = 2 * a * u + b * v + d
    sv = b * u + 2 * c * v + e
    inv = 1.0 / np.sqrt(1.0 + su * su + sv * sv)
    nl = np.stack([-su * inv, -sv * inv, inv], axis=1)
    return np.einsum("nij,nj->ni", frame, nl)


def surface_curvatures(points, centroid, frame, coeffs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Principal curvatures and first principal direction of each row's quadric.

    Computed from the first and second fundamental forms of the height field
    at the point's projection along ``e3``.  The sign convention is "convex
    is positive" with respect to the frame's ``e3``: a sphere whose frames
    point outward has ``k1 = k2 = +1/R``.

    Returns
    -------
    k1, k2 : (N,) float64
        Principal curvatures, ``k1 >= k2`` (1/unit of the coordinates).
    dir1 : (N, 3) float64
        Unit tangent direction of ``k1``.
    """
    u, v, _ = _to_frame(points, centroid, frame).T
    a, b, c, d, e, _ = coeffs.T
    su = 2 * a * u + b * v + d
    sv = b * u + 2 * c * v + e
    W = np.sqrt(1.0 + su * su + sv * sv)
    E, F, G = 1.0 + su * su, su * sv, 1.0 + sv * sv
    # second form with respect to e3-side normal; negate for "convex positive"
    L, M, N = -2 * a / W, -b / W, -2 * c / W
    det1 = E * G - F * F
    H = (E * N - 2 * F * M + G * L) / (2 * det1)
    K = (L * N - M * M) / det1
    disc = np.sqrt(np.maximum(H * H - K, 0.0))
    k1, k2 = H + disc, H - disc
    # eigenvector of (II - k1 I) x = 0, from whichever row is better conditioned
    r1 = np.stack([M - k1 * F, -(L - k1 * E)], axis=1)
    r2 = np.stack([N - k1 * G, -(M - k1 * F)], axis=1)
    use2 = np.einsum("ni,ni->n", r2, r2) > np.einsum("ni,ni->n", r1, r1)
    x = np.where(use2[:, None], r2, r1)
    nrm = np.sqrt(np.einsum("ni,ni->n", x, x))
    umbilic = nrm < 1e-12 * (np.abs(k1) + 1e-300) + 1e-300
    x = np.where(umbilic[:, None], np.array([1.0, 0.0]), x / np.where(nrm > 0, nrm, 1.0)[:, None])
    t_local = np.stack([x[:, 0], x[:, 1], su * x[:, 0] + sv * x[:, 1]], axis=1)
    t = np.einsum("nij,nj->ni", frame, t_local)
    t /= np.linalg.norm(t, axis=1)[:, None]
    return k1, k2, t


def turn_over(frames: np.ndarray, coeffs: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Copies of frames (P, 3, 3) and coefficients (P, 6) with the ``mask`` rows turned over.

    Turning a patch over negates ``e3`` and ``e2`` (the frame stays
    right-handed) and rewrites the quadric for ``(u, -v, -w)``:
    ``w' = -a u^2 + b u v' - c v'^2 - d u + e v' - f``, the same surface with
    its normals reversed.
    """
    mask = np.asarray(mask, dtype=bool)
    frames = frames.copy()
    coeffs = coeffs.copy()
    frames[mask, :, 1:] *= -1.0
    coeffs[mask] *= np.array([-1.0, 1.0, -1.0, -1.0, 1.0, -1.0])
    return frames, coeffs
