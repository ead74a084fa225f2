"""Recovered camera poses against the truth: a similarity (Umeyama) alignment of the
camera centres, then each camera's rotation and position error after it.

Examples:
    >>> errors = pose_errors(recovered_c2w, true_c2w)   # (N, 4, 4) each, same order
    >>> errors["rotation_deg"].max(), errors["position"].max() / errors["extent"]

References: Umeyama 1991, "Least-squares estimation of transformation parameters between
two point patterns" (IEEE TPAMI 13(4)).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R (3, 3), t (3,)) minimising sum |dst - (s R src + t)|^2 over (N, 3) points.

    N >= 3 points not all on one line; R is a rotation (det +1).
    """
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"umeyama needs two (N >= 3, 3) point sets, got {src.shape} and "
                         f"{dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ D @ Vt
    var = (a ** 2).sum() / len(src)
    if var <= 0:
        raise ValueError("umeyama: the source points coincide")
    s = float(np.trace(np.diag(S) @ D) / var)
    return s, R, mu_d - s * R @ mu_s


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Angle in degrees of (N, 3, 3) rotations (scipy's, exact near 0 where arccos of the
    trace is not)."""
    return np.degrees(Rotation.from_matrix(R).magnitude())


def pose_errors(c2w: np.ndarray, true_c2w: np.ndarray) -> dict:
    """Errors of (N, 4, 4) camera-to-world ``c2w`` against ``true_c2w`` (same axes
    convention, same order) after aligning the centres with :func:`umeyama`.

    Returns:
        {"rotation_deg": (N,), "position": (N,) in the truth's units, "extent": the largest
        distance between two true camera centres, "sim3": (s, R, t) recovered -> truth}.
    """
    s, R, t = umeyama(c2w[:, :3, 3], true_c2w[:, :3, 3])
    centres = s * c2w[:, :3, 3] @ R.T + t
    rotations = R @ c2w[:, :3, :3]
    relative = np.swapaxes(true_c2w[:, :3, :3], -1, -2) @ rotations
    true_centres = true_c2w[:, :3, 3]
    extent = float(np.linalg.norm(true_centres[:, None] - true_centres[None], axis=-1).max())
    return {"rotation_deg": rotation_angle_deg(relative),
            "position": np.linalg.norm(centres - true_centres, axis=-1),
            "extent": extent, "sim3": (s, R, t)}
