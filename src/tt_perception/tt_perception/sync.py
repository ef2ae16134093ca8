"""Time offset between unsynchronised cameras, from the ball itself (video files carry no
clock).

For a candidate offset d (camera k's clock minus camera 0's), camera k's detections are
interpolated linearly in time to the instants of camera 0's detections; a right offset puts
each pair on each other's epipolar line, x_k^T E x_0 = 0 with the essential matrix
E = [t_rel]x R_rel of the two calibrated poses. The offset minimises the median epipolar
distance (normalised image units), first over a grid of half frame periods, then by golden
section search inside the best grid cell.
"""

import numpy as np

from .camera import MAX_TIME_OFFSET_S
from .triangulate import relative_pose


def epipolar_cost(E, t0, x0, tk, xk, offset, max_gap):
    """Median epipolar distance of camera-0 detections (t0 (n,), x0 (n, 2) normalised) to
    camera k's (tk, xk) interpolated at t0 + offset, under the essential matrix ``E`` (3, 3)
    of the two poses; ``inf`` when fewer than 8 pairs exist."""
    if len(tk) < 2:                 # nothing to interpolate (a camera that never saw a ball)
        return np.inf
    q = t0 + offset
    j = np.searchsorted(tk, q)
    ok = (j > 0) & (j < len(tk))
    j = np.clip(j, 1, len(tk) - 1)
    ok &= (tk[j] - tk[j - 1]) <= max_gap
    if ok.sum() < 8:
        return np.inf
    j = j[ok]
    frac = ((q[ok] - tk[j - 1]) / (tk[j] - tk[j - 1]))[:, None]
    xi = xk[j - 1] + frac * (xk[j] - xk[j - 1])
    a = np.column_stack([x0[ok], np.ones(ok.sum())])
    b = np.column_stack([xi, np.ones(ok.sum())])
    line = a @ E.T                          # epipolar lines in camera k
    dist = np.abs(np.sum(line * b, axis=1)) / np.hypot(line[:, 0], line[:, 1])
    return float(np.median(dist))


def estimate_offset(cam0, camk, t0, x0, tk, xk, fps, max_offset=MAX_TIME_OFFSET_S):
    """Offset (s) of camera k's clock against camera 0's and its median epipolar distance.

    ``t0``, ``tk``: detection times (s, each camera's own clock), ``x0``, ``xk``: normalised
    coordinates (n, 2). Searched within +-``max_offset`` s.
    """
    t0, x0 = np.asarray(t0, float), np.asarray(x0, float)
    order = np.argsort(tk)
    tk, xk = np.asarray(tk, float)[order], np.asarray(xk, float)[order]
    period = 1.0 / fps
    gap = 2.5 * period
    R, t = relative_pose(cam0, camk)
    E = np.cross(np.eye(3), t) @ R          # [t]x R: x_k^T E x_0 = 0, the same for every d

    def cost(d):
        return epipolar_cost(E, t0, x0, tk, xk, d, gap)

    grid = np.arange(-max_offset, max_offset + 1e-12, 0.5 * period)
    costs = np.array([cost(d) for d in grid])
    if not np.isfinite(costs).any():
        return None, np.inf
    best = grid[int(np.argmin(costs))]
    lo, hi = best - 0.5 * period, best + 0.5 * period
    g = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    fa, fb = cost(a), cost(b)
    for _ in range(30):
        if fa < fb:
            hi, b, fb = b, a, fa
            a = hi - g * (hi - lo)
            fa = cost(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = cost(b)
    d = 0.5 * (lo + hi)
    return d, cost(d)
