"""Plane geometry shared by the track generator and the racing line."""

from __future__ import annotations

import numpy as np


def curvature(points: np.ndarray) -> np.ndarray:
    """Signed Menger curvature of a closed polyline at each point, 1/m (positive turning left)."""
    a = points - np.roll(points, 1, axis=0)
    b = np.roll(points, -1, axis=0) - points
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    denom = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1) * np.linalg.norm(a + b, axis=1)
    return 2.0 * cross / np.maximum(denom, 1e-12)
