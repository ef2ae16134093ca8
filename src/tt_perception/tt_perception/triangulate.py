"""Triangulation of one ball seen by N >= 2 calibrated cameras, with its covariance.

Inputs are undistorted normalised image coordinates (x/z, y/z) from
:meth:`tt_perception.camera.Camera.normalise` (OpenCV's iterative undistortion with explicit
termination criteria). The point is the linear N-view DLT solution (each camera gives two rows
x P3 - P1, y P3 - P2), refined by two Gauss-Newton steps on the reprojection error; its
covariance is that of the pixel noise propagated through the rays. A camera whose reprojection
error exceeds the gate is dropped when at least two others remain.
"""

import numpy as np


def dlt(cameras, normalised):
    """Linear N-view triangulation: table-frame point (3,) from normalised coordinates (N, 2).

    Solves A X = 0 (homogeneous X) in the least-squares sense by SVD, with the rows
    x (R3 X + t3) - (R1 X + t1) and y (R3 X + t3) - (R2 X + t2) of every camera.
    """
    rows = []
    for cam, (x, y) in zip(cameras, normalised, strict=True):
        P = np.hstack([cam.R, cam.t[:, None]])
        rows.append(x * P[2] - P[0])
        rows.append(y * P[2] - P[1])
    A = np.asarray(rows)
    # Equivalent inhomogeneous least squares (X[3] = 1) is faster and exact for a point in
    # front of the cameras.
    X, *_ = np.linalg.lstsq(A[:, :3], -A[:, 3], rcond=None)
    return X


def refine(cameras, normalised, X, pixel_sigma=0.5, iterations=2):
    """Gauss-Newton on the pixel reprojection error from ``X``.

    Returns ``(X, covariance (3, 3) m^2, residuals (N,) pixels)``. The covariance is
    sigma^2 (J^T J)^-1 with J the Jacobian of the pixel projections (f / z scaling).
    """
    for i in range(iterations + 1):
        J = []
        r = []
        for cam, (x, y) in zip(cameras, normalised, strict=True):
            Xc = cam.R @ X + cam.t
            z = Xc[2]
            f = cam.focal
            u, v = Xc[0] / z, Xc[1] / z
            # d(x/z)/dXc, d(y/z)/dXc, chained through R, scaled to pixels.
            jx = f * (cam.R[0] - u * cam.R[2]) / z
            jy = f * (cam.R[1] - v * cam.R[2]) / z
            J.extend([jx, jy])
            r.extend([f * (x - u), f * (y - v)])
        J = np.asarray(J)
        r = np.asarray(r)
        JtJ = J.T @ J
        step = np.linalg.solve(JtJ, J.T @ r)
        if i == iterations:
            break
        X = X + step
    residual = np.hypot(r[0::2], r[1::2])
    return X, pixel_sigma ** 2 * np.linalg.inv(JtJ), residual


def triangulate(cameras, normalised, pixel_sigma=0.5, max_reprojection=2.0):
    """Point, covariance and per-camera residual from N >= 2 views, or None when inconsistent.

    ``cameras``: list of :class:`tt_perception.camera.Camera`; ``normalised`` (N, 2).
    The camera with the largest reprojection error above ``max_reprojection`` (pixels) is
    dropped while at least two remain. Returns ``(X (3,), cov (3, 3), residual (N,), used)``
    with ``used`` the indices of the cameras kept, or None when no consistent pair exists or
    the point is behind a camera.
    """
    used = list(range(len(cameras)))
    normalised = np.asarray(normalised, dtype=float)
    while len(used) >= 2:
        cams = [cameras[i] for i in used]
        X = dlt(cams, normalised[used])
        if not np.all(np.isfinite(X)):
            return None
        if any((c.R @ X + c.t)[2] <= 0.05 for c in cams):
            return None
        X, cov, residual = refine(cams, normalised[used], X, pixel_sigma)
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
