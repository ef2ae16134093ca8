"""Triangulation of one ball seen by N >= 2 calibrated cameras, with its covariance.

Inputs are undistorted normalised image coordinates (x/z, y/z) from
:meth:`tt_perception.camera.Camera.normalise` (OpenCV's iterative undistortion with explicit
termination criteria). The point is the linear N-view DLT solution (each camera gives two rows
x P3 - P1, y P3 - P2), refined by a Gauss-Newton step on the reprojection error; its
covariance is that of the pixel noise propagated through the rays. A camera whose reprojection
error exceeds the gate is dropped when at least two others remain.
"""

import numpy as np


def _stack(cameras):
    """Rotations (N, 3, 3), translations (N, 3) and focal lengths (N,) of the cameras."""
    return (np.array([c.R for c in cameras]), np.array([c.t for c in cameras]),
            np.array([c.focal for c in cameras]))


def dlt(cameras, normalised):
    """Linear N-view triangulation: table-frame point (3,) from normalised coordinates (N, 2).

    Least squares over the rows x (R3 X + t3) - (R1 X + t1) = 0 and
    y (R3 X + t3) - (R2 X + t2) = 0 of every camera (the DLT with X's last coordinate 1,
    which holds for a point in front of the cameras).
    """
    R, t, _ = _stack(cameras)
    x, y = normalised[:, 0:1], normalised[:, 1:2]
    A = np.vstack([x * R[:, 2] - R[:, 0], y * R[:, 2] - R[:, 1]])
    b = np.concatenate([t[:, 0] - x[:, 0] * t[:, 2], t[:, 1] - y[:, 0] * t[:, 2]])
    return np.linalg.solve(A.T @ A, A.T @ b)


MAX_CONDITION = 1e10
"""Largest condition number of J^T W J (:func:`refine`) taken as fixing a point: two cameras
a metre apart give under 10, a 1 cm baseline at 3 m ~5e5, two cameras at one place ~1e16
(singular to working precision: a point anywhere on the ray)."""


def _information(Jw):
    """J^T W J (3, 3) of the weighted Jacobian ``Jw``; raises ``numpy.linalg.LinAlgError``
    when it is singular to working precision (:data:`MAX_CONDITION`; NaN too)."""
    info = Jw.T @ Jw
    if not np.linalg.cond(info) < MAX_CONDITION:
        raise np.linalg.LinAlgError('the rays fix no point (singular system)')
    return info


def _reprojection(R, t, f, normalised, X):
    """Pixel residuals (2N,) and their Jacobian (2N, 3) with respect to X."""
    Xc = R @ X + t
    z = Xc[:, 2:3]
    uv = Xc[:, :2] / z
    # d(x/z)/dX = (R1 - (x/z) R3) / z, scaled to pixels by f.
    scale = (f[:, None] / z)
    jx = scale * (R[:, 0] - uv[:, 0:1] * R[:, 2])
    jy = scale * (R[:, 1] - uv[:, 1:2] * R[:, 2])
    r = f[:, None] * (normalised - uv)
    return np.concatenate([r[:, 0], r[:, 1]]), np.vstack([jx, jy])


def refine(cameras, normalised, X, pixel_sigma=0.5, iterations=1):
    """Gauss-Newton on the pixel reprojection error from ``X``, each camera weighted by its
    ``pixel_sigma`` (a number, or one per camera).

    Returns ``(X, covariance (3, 3) m^2, residuals (N,) pixels)``. The covariance is
    (J^T W J)^-1 with J the Jacobian of the pixel projections and W = diag(1 / sigma^2).
    Raises ``numpy.linalg.LinAlgError`` when the rays fix no point (J^T W J singular,
    :data:`MAX_CONDITION`).
    """
    R, t, f = _stack(cameras)
    n = len(cameras)
    w = 1.0 / np.broadcast_to(np.asarray(pixel_sigma, dtype=float), (n,))
    w = np.concatenate([w, w])[:, None]
    for _ in range(iterations):
        r, J = _reprojection(R, t, f, normalised, X)
        Jw = J * w
        X = X + np.linalg.solve(Jw.T @ Jw, Jw.T @ (r * w[:, 0]))   # checked below
    r, J = _reprojection(R, t, f, normalised, X)
    Jw = J * w
    residual = np.hypot(r[:n], r[n:])
    return X, np.linalg.inv(_information(Jw)), residual


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
    normalised = np.asarray(normalised, dtype=float)
    sigmas = np.broadcast_to(np.asarray(pixel_sigma, dtype=float), (len(cameras),))
    while len(used) >= 2:
        cams = [cameras[i] for i in used]
        try:
            X = dlt(cams, normalised[used])
            if not np.all(np.isfinite(X)) or any((c.R @ X + c.t)[2] <= 0.05 for c in cams):
                return None
            X, cov, residual = refine(cams, normalised[used], X, sigmas[used])
        except np.linalg.LinAlgError:
            return None
        worst = int(np.argmax(residual))
        if residual[worst] <= max_reprojection:
            return X, cov, residual, used
        if len(used) == 2:
            return None
        used.pop(worst)
    return None


def relative_pose(cam_a, cam_b):
    """Rotation and translation from camera a's optical frame to camera b's:
    X_b = R X_a + t."""
    R = cam_b.R @ cam_a.R.T
    return R, cam_b.t - R @ cam_a.t
