"""Triangulation of one ball seen by N >= 2 calibrated cameras, with its covariance.

Inputs are undistorted normalised image coordinates (x/z, y/z) from
:meth:`tt_perception.camera.Camera.normalise` (OpenCV's iterative undistortion with explicit
termination criteria). The point is the linear N-view DLT solution (each camera gives two rows
x P3 - P1, y P3 - P2), refined by a Gauss-Newton step on the reprojection error; its
covariance is that of the pixel noise propagated through the rays. A camera whose reprojection
error exceeds the gate is dropped when at least two others remain.
"""

import math

from numba import njit
import numpy as np

_NJIT = {'cache': True, 'nogil': True, 'error_model': 'numpy'}
"""The kernels below are compiled (numba) and run without the GIL: a ball's point is
triangulated on every camera frame, beside the camera threads. A division by zero gives inf
or nan, as numpy's does, not ZeroDivisionError."""

MAX_CONDITION = 1e10
"""Largest condition number of J^T W J (:func:`refine`) taken as fixing a point: two cameras
a metre apart give under 10, a 1 cm baseline at 3 m ~5e5, two cameras at one place ~1e16
(singular to working precision: a point anywhere on the ray)."""

MIN_DEPTH = 0.05
"""Nearest a triangulated point may be to a camera along its axis, m (:func:`triangulate`)."""


def _stack(cameras):
    """Rotations (N, 3, 3), translations (N, 3) and focal lengths (N,) of the cameras."""
    return (np.array([c.R for c in cameras], dtype=float),
            np.array([c.t for c in cameras], dtype=float),
            np.array([c.focal for c in cameras], dtype=float))


@njit(**_NJIT)
def _dlt(R, t, xy):
    """:func:`dlt` on stacked cameras: the normal equations of the 2N rows, solved."""
    ata = np.zeros((3, 3))
    atb = np.zeros(3)
    a = np.empty(3)
    for k in range(R.shape[0]):
        for row in range(2):
            c = xy[k, row]
            for j in range(3):
                a[j] = c * R[k, 2, j] - R[k, row, j]
            b = t[k, row] - c * t[k, 2]
            for i in range(3):
                atb[i] += a[i] * b
                for j in range(3):
                    ata[i, j] += a[i] * a[j]
    return np.linalg.solve(ata, atb)


@njit(**_NJIT)
def _refine(R, t, f, xy, w, X, iterations):
    """:func:`refine` on stacked cameras with weights ``w`` (1 / sigma per camera):
    (X, covariance, residuals (N,) pixels, fixed). ``fixed`` False: J^T W J at the last X is
    singular to working precision (:data:`MAX_CONDITION`; the covariance is then nan).
    An exactly singular step raises ``numpy.linalg.LinAlgError`` (as numpy's solve)."""
    n = R.shape[0]
    jw = np.empty((2 * n, 3))      # the weighted Jacobian of the pixel projections
    rw = np.empty(2 * n)           # the weighted pixel residuals, x rows then y rows
    residual = np.empty(n)         # each camera's pixel residual, unweighted
    X = X.copy()
    for it in range(max(iterations, 0) + 1):
        for k in range(n):
            xc = R[k] @ X + t[k]
            x, y = xc[0] / xc[2], xc[1] / xc[2]
            # d(x/z)/dX = (R1 - (x/z) R3) / z, scaled to pixels by f.
            scale = f[k] / xc[2] * w[k]
            for j in range(3):
                jw[k, j] = scale * (R[k, 0, j] - x * R[k, 2, j])
                jw[n + k, j] = scale * (R[k, 1, j] - y * R[k, 2, j])
            rx, ry = f[k] * (xy[k, 0] - x), f[k] * (xy[k, 1] - y)
            rw[k], rw[n + k] = rx * w[k], ry * w[k]
            residual[k] = math.hypot(rx, ry)
        info = jw.T @ jw
        if it < iterations:
            X = X + np.linalg.solve(info, jw.T @ rw)
    if not np.linalg.cond(info) < MAX_CONDITION:
        return X, np.full((3, 3), np.nan), residual, False
    # C order, as numpy's inverse is (LAPACK's is Fortran): the filter's kernels that take
    # the covariance are compiled for C-ordered arrays (camstream.warm_up).
    return X, np.ascontiguousarray(np.linalg.inv(info)), residual, True


@njit(**_NJIT)
def _triangulate(R, t, f, xy, w):
    """:func:`dlt` then :func:`refine` on stacked cameras: (X, covariance, residuals,
    status), status 0 when fixed, 1 when the point is not finite or not in front of every
    camera (:data:`MIN_DEPTH`), 2 when the rays fix no point."""
    X = _dlt(R, t, xy)
    if not np.all(np.isfinite(X)):
        return X, np.zeros((3, 3)), np.zeros(R.shape[0]), 1
    for k in range(R.shape[0]):
        if not (R[k, 2] @ X + t[k, 2]) > MIN_DEPTH:
            return X, np.zeros((3, 3)), np.zeros(R.shape[0]), 1
    X, cov, residual, fixed = _refine(R, t, f, xy, w, X, 1)
    return X, cov, residual, 0 if fixed else 2


def _weights(pixel_sigma, n):
    """1 / sigma per camera (C-contiguous, as the kernels were compiled for)."""
    if np.ndim(pixel_sigma) == 0:          # one for all: the common case, 10 times faster
        return np.full(n, 1.0 / float(pixel_sigma))
    return np.ascontiguousarray(1.0 / np.broadcast_to(np.asarray(pixel_sigma, dtype=float),
                                                      (n,)))


def _observations(normalised, n):
    """``normalised`` as a fresh C-ordered float (n, 2) array (the kernels' one compiled
    signature; they index it unchecked); ValueError when it is not one row per camera."""
    out = np.array(normalised, dtype=float, order='C')
    if out.shape != (n, 2):
        raise ValueError(f'normalised coordinates of shape {out.shape} for {n} cameras '
                         f'(expected ({n}, 2))')
    return out


def dlt(cameras, normalised):
    """Linear N-view triangulation: table-frame point (3,) from normalised coordinates (N, 2).

    Least squares over the rows x (R3 X + t3) - (R1 X + t1) = 0 and
    y (R3 X + t3) - (R2 X + t2) = 0 of every camera (the DLT with X's last coordinate 1,
    which holds for a point in front of the cameras).
    """
    R, t, _ = _stack(cameras)
    return _dlt(R, t, _observations(normalised, len(cameras)))


def refine(cameras, normalised, X, pixel_sigma=0.5, iterations=1):
    """Gauss-Newton on the pixel reprojection error from ``X``, each camera weighted by its
    ``pixel_sigma`` (a number, or one per camera).

    Returns ``(X, covariance (3, 3) m^2, residuals (N,) pixels)``. The covariance is
    (J^T W J)^-1 with J the Jacobian of the pixel projections and W = diag(1 / sigma^2).
    Raises ``numpy.linalg.LinAlgError`` when the rays fix no point (J^T W J singular at the
    last X, :data:`MAX_CONDITION`, or a step's system exactly singular).
    """
    R, t, f = _stack(cameras)
    X, cov, residual, fixed = _refine(R, t, f, _observations(normalised, len(cameras)),
                                      _weights(pixel_sigma, len(cameras)),
                                      np.array(X, dtype=float, order='C').reshape(3),
                                      int(iterations))
    if not fixed:
        raise np.linalg.LinAlgError('the rays fix no point (singular system)')
    return X, cov, residual


def triangulate(cameras, normalised, pixel_sigma=0.5, max_reprojection=2.0):
    """Point, covariance and per-camera residual from N >= 2 views, or None when inconsistent.

    ``cameras``: list of :class:`tt_perception.camera.Camera`; ``normalised`` (N, 2);
    ``pixel_sigma``: a number or one per camera, pixels.
    The camera with the largest reprojection error above ``max_reprojection`` (pixels) is
    dropped while at least two remain. Returns ``(X (3,), cov (3, 3), residual (N,), used)``
    with ``used`` the indices of the cameras kept, or None when no consistent pair exists,
    the point is behind a camera or the rays fix no point (cameras at one place, parallel
    rays: a singular system).
    """
    used = list(range(len(cameras)))
    R, t, f = _stack(cameras)
    xy = _observations(normalised, len(cameras))
    w = _weights(pixel_sigma, len(cameras))
    while len(used) >= 2:
        # All cameras: the arrays as they are (indexing copies them, each time).
        views = ((R, t, f, xy, w) if len(used) == len(cameras)
                 else (R[used], t[used], f[used], xy[used], w[used]))
        try:
            X, cov, residual, status = _triangulate(*views)
        except np.linalg.LinAlgError:      # exactly singular normal equations, or nan / inf
            return None
        if status != 0:
            return None
        worst = int(np.argmax(residual))
        if residual[worst] <= max_reprojection:
            return X, cov, residual, used
        if len(used) == 2:
            return None
        used.pop(worst)
    return None


def warm_up():
    """Load the compiled kernels (numba) before the first ball needs them: two cameras a
    metre apart and a point 3 m in front of them."""
    R = np.array([np.eye(3), np.eye(3)])
    t = np.array([[0.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    xy = np.array([[0.0, 0.0], [-1.0 / 3.0, 0.0]])
    X, _, _, _ = _triangulate(R, t, np.full(2, 500.0), xy, np.ones(2))
    _refine(R, t, np.full(2, 500.0), xy, np.ones(2), X, 1)
    _dlt(R, t, xy)


def relative_pose(cam_a, cam_b):
    """Rotation and translation from camera a's optical frame to camera b's:
    X_b = R X_a + t."""
    R = cam_b.R @ cam_a.R.T
    return R, cam_b.t - R @ cam_a.t
