"""Distance from points to a 3-D polyline (the path as the recorder and ``inspect`` see it).

The recorder knows the path only as sampled points (m, paper frame ENU); the distance to
that polyline is within the sampling sag of the distance to the true path.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Polyline"]


class Polyline:
    """Segments of ``points_m`` (N ≥ 2 rows of x, y, z in m, all finite)."""

    def __init__(self, points_m: object) -> None:
        pts = np.asarray(points_m, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise ValueError(f"points_m: expected an (N, 3) array with N >= 2, got shape "
                             f"{pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("points_m: contains NaN or inf")
        self.points_m = pts
        self._a = pts[:-1]
        self._d = pts[1:] - pts[:-1]
        dd = np.einsum("ij,ij->i", self._d, self._d)
        self._dd = np.where(dd > 0.0, dd, 1.0)     # a repeated point is a zero-length segment

    def distance(self, p_m: object) -> float:
        """Distance (m) from one point to the polyline."""
        w = np.asarray(p_m, dtype=float) - self._a
        t = np.clip(np.einsum("ij,ij->i", w, self._d) / self._dd, 0.0, 1.0)
        r = w - t[:, None] * self._d
        return float(np.sqrt(np.min(np.einsum("ij,ij->i", r, r))))

    def distances(self, p_m: np.ndarray, block: int = 2048) -> np.ndarray:
        """Distances (m) from each row of ``p_m`` (M, 3), in blocks to bound memory."""
        p = np.asarray(p_m, dtype=float).reshape(-1, 3)
        out = np.empty(len(p))
        for s in range(0, len(p), block):
            w = p[s:s + block, None, :] - self._a[None, :, :]            # (B, N, 3)
            t = np.clip(np.einsum("bnk,nk->bn", w, self._d) / self._dd, 0.0, 1.0)
            r = w - t[..., None] * self._d[None, :, :]
            out[s:s + block] = np.sqrt(np.min(np.einsum("bnk,bnk->bn", r, r), axis=1))
        return out
