"""Rotations as rotation vectors (axis times angle [rad]) and matrices: a cloth grid's pose (``scenario``) and a
box collider's (``colliders``)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike


def rotation_matrix(rvec: ArrayLike) -> np.ndarray:
    """Rodrigues: the rotation matrix of a rotation vector (axis * angle [rad]); the same as cv2.Rodrigues."""
    r = np.asarray(rvec, dtype=np.float64).reshape(3)
    th = float(np.linalg.norm(r))
    if th < 1e-15:
        return np.eye(3)
    k = r / th
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(th) * Kx + (1.0 - math.cos(th)) * (Kx @ Kx)


def rotation_vector(R: ArrayLike) -> np.ndarray:
    """The rotation vector (axis * angle, angle in [0, pi]) of a rotation matrix; inverse of rotation_matrix."""
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    c = max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))
    th = math.acos(c)
    if th < 1e-12:
        return np.zeros(3)
    if th > math.pi - 1e-6:  # near pi: the axis from the symmetric part
        B = (R + np.eye(3)) / 2.0
        k = np.sqrt(np.maximum(np.diag(B), 0.0))
        i = int(np.argmax(k))
        k = B[i] / max(k[i], 1e-12)
        k /= np.linalg.norm(k)
        return k * th
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2.0 * math.sin(th))
    return w * th
