"""Extended Kalman filter of the ball state s = [p, v, w] (9,) on tt_prediction's model.

Frames and units: ``table`` frame, p in m, v in m/s, w (spin) in rad/s, time in s.

Prediction integrates the flight model (MODEL.md eq. 8, ``tt_prediction.model
.flight_derivative``) with tt_prediction.integrate's RK4 step and propagates the covariance
with the Jacobian of eq. 8,

    d(a)/dv = -k_D (|u| I + u u^T / |u|) + k_M [w]x,     d(a)/dw = -k_M [u]x,

with u = v - wind, k_D = C_D rho A / (2 m), k_M = 4/3 C_M pi rho r^3 / m. The spin enters the
measurements only through the Magnus term k_M w x u, so in flight only the spin across the
velocity is observed: the component along u keeps its prior variance (it is reported as
unknown, not invented) until a table bounce, whose rebound (eqs. 1-6) depends on it.

A bounce is handled when the predicted centre reaches z = r over the table moving down: the
state is integrated to the contact, the rebound applied (``table_rebound_inplace``) with its
Jacobian (finite differences) and extra noise for the rebound parameters' uncertainty.

Measurements are triangulated positions with their covariance; an innovation whose squared
Mahalanobis distance exceeds ``gate`` is rejected (outlier gating).
"""

import dataclasses
import math

import numpy as np
from tt_prediction.integrate import _rk4 as rk4_step
from tt_prediction.model import table_rebound_inplace
from tt_prediction.params import ModelParams
from tt_prediction.table import HALF_LENGTH, HALF_WIDTH


@dataclasses.dataclass
class FilterConfig:
    """Noise and gating of :class:`BallFilter` (SI units)."""

    accel_noise: float = 0.05
    """Unmodelled acceleration as a white-noise density, m/s^2 / sqrt(Hz)."""
    spin_noise: float = 2.0
    """Random walk of the spin, rad/s / sqrt(s)."""
    spin_prior: float = 250.0
    """Prior standard deviation of each spin component, rad/s (unknown spin)."""
    bounce_velocity_noise: float = 0.15
    """Standard deviation added to each velocity component at a bounce, m/s."""
    bounce_spin_noise: float = 25.0
    """Standard deviation added to each spin component at a bounce, rad/s."""
    gate: float = 25.0
    """Squared Mahalanobis distance above which a measurement is an outlier (3 dof)."""
    robust: float = 9.0
    """Squared Mahalanobis distance above which a measurement's covariance is inflated."""
    max_step: float = 1.0 / 150.0
    """Longest integration step, s."""


_EYE9 = np.eye(9)
_EYE3 = np.eye(3)


def skew(a):
    """Cross-product matrix [a]x, so that [a]x b = a x b."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


class BallFilter:
    """EKF of one ball. Create with :meth:`start`, then :meth:`predict` and :meth:`update`."""

    def __init__(self, params=None, config=None):
        self.params = params or ModelParams()
        self.config = config or FilterConfig()
        self.P_model = self.params.packed()
        p = self.params
        self.k_drag = 0.5 * p.c_d * p.air_density * p.area / p.mass         # eq. 8 drag / m
        self.k_lift = 4.0 / 3.0 * p.c_m * np.pi * p.air_density * p.radius ** 3 / p.mass
        self.wind = np.asarray(p.wind, dtype=float)
        self.x = np.zeros(9)
        self.P = np.eye(9)
        self.t = 0.0
        self.bounces = 0
        self._work = [np.empty(9) for _ in range(5)]     # RK4 stages and sub-step state
        self._q_cache = {}

    def start(self, t, position, velocity, position_cov, velocity_cov):
        """Initialise at time ``t`` (s) from a position and velocity with covariances."""
        self.t = float(t)
        self.x = np.concatenate([position, velocity, np.zeros(3)]).astype(float)
        self.P = np.zeros((9, 9))
        self.P[:3, :3] = position_cov
        self.P[3:6, 3:6] = velocity_cov
        self.P[6:, 6:] = np.eye(3) * self.config.spin_prior ** 2
        self.bounces = 0

    def _jacobian(self, s):
        """Continuous-time Jacobian F (9, 9) of the flight derivative (eq. 8) at ``s``."""
        u = s[3:6] - self.wind
        w = s[6:9]
        speed = max(math.sqrt(u @ u), 1e-9)
        F = np.zeros((9, 9))
        F[0:3, 3:6] = _EYE3
        F[3:6, 3:6] = (-self.k_drag * (speed * _EYE3 + np.outer(u, u) / speed)
                       + self.k_lift * skew(w))
        F[3:6, 6:9] = -self.k_lift * skew(u)
        return F

    def _process_noise(self, h):
        """Q (9, 9) of white unmodelled acceleration and a spin random walk over ``h`` s."""
        Q = self._q_cache.get(h)
        if Q is None:
            q = self.config.accel_noise ** 2
            Q = np.zeros((9, 9))
            Q[:3, :3] = np.eye(3) * q * h ** 3 / 3.0
            Q[:3, 3:6] = Q[3:6, :3] = np.eye(3) * q * h ** 2 / 2.0
            Q[3:6, 3:6] = np.eye(3) * q * h
            Q[6:, 6:] = np.eye(3) * self.config.spin_noise ** 2 * h
            if len(self._q_cache) < 64:
                self._q_cache[h] = Q
        return Q

    def _propagate(self, h):
        """Advance state and covariance by ``h`` s of flight."""
        F = self._jacobian(self.x) * h
        Phi = _EYE9 + F + 0.5 * F @ F
        x = np.empty(9)
        rk4_step(self.x, h, self.P_model, x, *self._work)    # eq. 8
        self.x = x
        self.P = Phi @ self.P @ Phi.T + self._process_noise(h)

    def _bounce(self):
        """Apply the table rebound (eqs. 1-6) to the state and its covariance."""
        before = self.x.copy()
        after = before.copy()
        table_rebound_inplace(after, self.P_model)
        J = np.eye(9)
        for i in range(3, 9):
            d = 1e-4 if i < 6 else 1e-2
            s = before.copy()
            s[i] += d
            table_rebound_inplace(s, self.P_model)
            J[3:, i] = (s[3:] - after[3:]) / d
        self.x = after
        cfg = self.config
        self.P = J @ self.P @ J.T
        self.P[3:6, 3:6] += _EYE3 * cfg.bounce_velocity_noise ** 2
        self.P[6:, 6:] += _EYE3 * cfg.bounce_spin_noise ** 2
        self.bounces += 1

    def predict(self, t):
        """Advance the filter to time ``t`` (s), bouncing on the table when the ball does."""
        r = self.params.radius
        while t - self.t > 1e-9:
            h = min(self.config.max_step, t - self.t)
            z0 = self.x[2]
            x_save, P_save = self.x.copy(), self.P.copy()
            self._propagate(h)
            on_table = (abs(self.x[0]) <= HALF_LENGTH + r) and (abs(self.x[1]) <= HALF_WIDTH + r)
            if self.x[2] < r <= z0 and self.x[5] < 0.0 and on_table:
                # Step to the contact (linear in z over the step), rebound, go on.
                tau = h * (z0 - r) / max(z0 - self.x[2], 1e-12)
                if tau <= 1e-9:
                    # Already in contact (rolling on the surface): no impact, stay on it.
                    self.x[2], self.x[5] = r, max(self.x[5], 0.0)
                    self.t += h
                    continue
                self.x, self.P = x_save, P_save
                self._propagate(tau)
                self.x[2] = r
                self._bounce()
                self.t += tau
                continue
            self.t += h

    def innovation(self, z, R):
        """Innovation y (3,), its covariance S (3, 3) and squared Mahalanobis distance."""
        y = np.asarray(z, dtype=float) - self.x[:3]
        S = self.P[:3, :3] + R
        return y, S, float(y @ np.linalg.solve(S, y))

    def update(self, z, R):
        """Fuse a position measurement ``z`` (3,), m, covariance ``R`` (3, 3), m^2.

        Returns False (and leaves the state) when it fails the Mahalanobis gate.
        """
        y, S, d2 = self.innovation(z, R)
        if d2 > self.config.gate:
            return False
        if d2 > self.config.robust:
            # Huber-like: a measurement far out in its distribution (a ball crossing a line
            # of the same colour) counts with a proportionally inflated covariance.
            R = R * (d2 / self.config.robust)
            S = self.P[:3, :3] + R
        self._fuse(slice(0, 3), y, S, R)
        return True

    def update_spin(self, w, R):
        """Fuse a measured spin ``w`` (3,), rad/s, covariance ``R`` (3, 3) (e.g. from a marked
        ball); it fills in the component along the velocity that flight cannot observe."""
        y = np.asarray(w, dtype=float) - self.x[6:]
        self._fuse(slice(6, 9), y, self.P[6:, 6:] + R, R)

    def _fuse(self, part, y, S, R):
        """Kalman update of a direct measurement of the state's ``part`` (H selects it):
        innovation ``y`` (3,), its covariance ``S`` and the measurement's ``R`` (3, 3)."""
        K = np.linalg.solve(S, self.P[part, :]).T      # P H^T S^-1
        self.x = self.x + K @ y
        IKH = np.eye(9)
        IKH[:, part] -= K
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T     # Joseph form

    def spin_variance_along_velocity(self):
        """Variance (rad/s)^2 of the spin component along the current velocity."""
        u = self.x[3:6] / max(np.linalg.norm(self.x[3:6]), 1e-9)
        return float(u @ self.P[6:, 6:] @ u)
