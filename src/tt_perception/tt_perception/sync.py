"""Time offset between unsynchronised cameras, from the ball itself (video files carry no
clock).

Where frames with a single detection are too few (other moving things beside the ball: a
racket, a swinging disc), each camera's detections are linked into image tracks
(:func:`image_tracks`: a detection continues the track whose last point is nearest, within
a step and a gap), every pair of moving tracks of camera 0 and camera k is tried
(:func:`estimate_offset_tracks`), and the offset the most frames support kept (two views of
one object agree at the right offset, two different objects at none).

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


def epipolar_distances(E, t0, x0, tk, xk, offset, max_gap):
    """Epipolar distances (normalised units) of camera-0 detections (t0 (n,), x0 (n, 2)
    normalised) to camera k's (tk sorted, xk) interpolated at t0 + ``offset``, under the
    essential matrix ``E`` (3, 3) of the two poses; only where camera k has detections on
    both sides within ``max_gap`` s."""
    if len(tk) < 2:                 # nothing to interpolate (a camera that never saw a ball)
        return np.empty(0)
    q = t0 + offset
    j = np.searchsorted(tk, q)
    ok = (j > 0) & (j < len(tk))
    j = np.clip(j, 1, len(tk) - 1)
    ok &= (tk[j] - tk[j - 1]) <= max_gap
    j = j[ok]
    frac = ((q[ok] - tk[j - 1]) / (tk[j] - tk[j - 1]))[:, None]
    xi = xk[j - 1] + frac * (xk[j] - xk[j - 1])
    a = np.column_stack([x0[ok], np.ones(ok.sum())])
    b = np.column_stack([xi, np.ones(ok.sum())])
    line = a @ E.T                          # epipolar lines in camera k
    return np.abs(np.sum(line * b, axis=1)) / np.hypot(line[:, 0], line[:, 1])


def epipolar_cost(E, t0, x0, tk, xk, offset, max_gap):
    """Median of :func:`epipolar_distances`; ``inf`` when fewer than 8 pairs exist."""
    dist = epipolar_distances(E, t0, x0, tk, xk, offset, max_gap)
    return float(np.median(dist)) if len(dist) >= 8 else np.inf


def estimate_offset(cam0, camk, t0, x0, tk, xk, fps, max_offset=MAX_TIME_OFFSET_S,
                    centre=0.0):
    """Offset (s) of camera k's clock against camera 0's and its median epipolar distance.

    ``t0``, ``tk``: detection times (s, each camera's own clock), ``x0``, ``xk``: normalised
    coordinates (n, 2). Searched within ``centre`` +-``max_offset`` s.
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

    grid = centre + np.arange(-max_offset, max_offset + 1e-12, 0.5 * period)
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


AGREE_PX = 1.5
"""A frame supports an offset when its pair is within this many pixels of the epipolar line
(:func:`estimate_offset_tracks`; a right offset on a detected ball gives under a pixel)."""
MIN_SUPPORT = 15
"""Frames a pair of image tracks must support its offset with to count."""
MAX_STEP = 0.06
"""Largest move of a detection between a track's frames, normalised image units per frame
(about 50 pixels at f = 800: a 20 m/s ball 2.5 m away at 150 fps moves 43)."""
MIN_MOTION = 0.01
"""An image track that moves less than this over its frames (normalised units, about 8
pixels) says nothing of time: left out."""


def image_tracks(times, points, period, max_step=MAX_STEP, max_gap=2.5):
    """Detections of one camera linked into image tracks: ``times`` (n,) s and ``points``
    (n, 2) normalised, several per frame allowed, in any order; a detection continues the
    track whose last point is nearest, within ``max_step`` per frame period (``period``, s)
    and ``max_gap`` periods, nearest pairs first. Returns [(t (m,), x (m, 2))] of the tracks
    of 8 points or more that move at least :data:`MIN_MOTION`."""
    times, points = np.asarray(times, float), np.asarray(points, float).reshape(-1, 2)
    order = np.argsort(times, kind='stable')
    tracks, live = [], []           # [[times], [points]]: all, and those that may go on
    i = 0
    while i < len(order):
        j = i
        while j < len(order) and times[order[j]] == times[order[i]]:
            j += 1
        t = times[order[i]]
        frame = [points[k] for k in order[i:j]]
        live = [tr for tr in live if t - tr[0][-1] <= max_gap * period]
        pairs = []
        for b, tr in enumerate(live):
            reach = max_step * max(1.0, (t - tr[0][-1]) / period)
            for a, x in enumerate(frame):
                d = float(np.linalg.norm(x - tr[1][-1]))
                if d <= reach:
                    pairs.append((d, a, b))
        pairs.sort()
        used_x, used_tr = set(), set()
        for _, a, b in pairs:
            if a in used_x or b in used_tr:
                continue
            used_x.add(a)
            used_tr.add(b)
            live[b][0].append(t)
            live[b][1].append(frame[a])
        new = [[[t], [x]] for a, x in enumerate(frame) if a not in used_x]
        tracks += new
        live += new
        i = j
    out = []
    for t, x in tracks:
        x = np.array(x)
        if len(t) >= 8 and np.ptp(x, axis=0).max() >= MIN_MOTION:
            out.append((np.array(t), x))
    return out


def estimate_offset_tracks(cam0, camk, tracks0, tracksk, fps, max_offset=MAX_TIME_OFFSET_S):
    """Offset (s) of camera k's clock against camera 0's, and its median epipolar distance,
    from image tracks of each (``tracks0``, ``tracksk``: :func:`image_tracks`).

    Each pair of tracks gets its own :func:`estimate_offset`, and its support: the frames it
    pairs within :data:`AGREE_PX` of the epipolar lines at that offset. The pair with the most
    support (at least :data:`MIN_SUPPORT` frames: a short pair reaches a small median by
    chance among many offsets) gives the offset. The tracks of every pair that agrees with it
    too (its own offset within a frame period, its support at least MIN_SUPPORT: one
    object's track broken where another crossed it) are then taken together and the offset
    searched again within a frame period; kept when it has at least the pair's support.
    ``(None, inf)`` when no pair has that support."""
    period = 1.0 / fps
    R, t = relative_pose(cam0, camk)
    E = np.cross(np.eye(3), t) @ R
    tol = AGREE_PX / camk.focal

    def support(t0, x0, tk, xk, offset):
        """Frames within AGREE_PX of the epipolar lines at ``offset``."""
        return int(np.sum(epipolar_distances(E, t0, x0, tk, xk, offset, 2.5 * period) <= tol))

    pairs = []
    span = MIN_SUPPORT * period         # the least time two tracks must share
    for i, (t0, x0) in enumerate(tracks0):
        for j, (tk, xk) in enumerate(tracksk):
            # Only offsets at which the two share MIN_SUPPORT frames can win.
            lo = max(tk[0] - t0[-1] + span, -max_offset)
            hi = min(tk[-1] - t0[0] - span, max_offset)
            if min(len(t0), len(tk)) < MIN_SUPPORT or lo > hi:
                continue
            offset, cost = estimate_offset(cam0, camk, t0, x0, tk, xk, fps,
                                           0.5 * (hi - lo) + period, 0.5 * (lo + hi))
            if offset is not None:
                n = support(t0, x0, tk, xk, offset)
                if n >= MIN_SUPPORT:
                    pairs.append((n, -cost, offset, i, j))
    if not pairs:
        return None, np.inf
    n, cost, offset, _, _ = max(pairs)
    cost = -cost
    agree = [(i, j) for _, _, o, i, j in pairs if abs(o - offset) <= period]

    def joined(tracks, chosen):
        t = np.concatenate([tracks[i][0] for i in chosen])
        x = np.concatenate([tracks[i][1] for i in chosen])
        t, first = np.unique(t, return_index=True)      # one point an instant: interpolable
        return t, x[first]

    t0, x0 = joined(tracks0, sorted({i for i, _ in agree}))
    tk, xk = joined(tracksk, sorted({j for _, j in agree}))
    refined, refined_cost = estimate_offset(cam0, camk, t0, x0, tk, xk, fps, period, offset)
    if refined is None or support(t0, x0, tk, xk, refined) < n:
        return offset, cost
    return refined, refined_cost
