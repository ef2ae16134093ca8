"""Eq. 7 (MODEL.md, racket rubber rebound) against cases worked out by hand in a racket frame
rotated away from the table frame, for tt's racket_rebound and the tests' reference.

Rubber chosen for round numbers: m = 2.7e-3 kg, r = 0.02 m, k_p = 1.35e-3 kg/s, e_r = 0.8, so
K_v = k_p / m = 0.5, K_v r = 0.01 m, K_w = k_p / I = 1875 (I = 2/3 m r^2 = 7.2e-7 kg m^2),
so K_w r^2 = 1.5 K_v = 0.75 and K_w r = 37.5 1/m.

Racket frame (z = the normal) tilted 53.13 deg about the table's y axis:
    n = z_r = (0.6, 0, 0.8),   x_r = (0.8, 0, -0.6),   y_r = z_r x x_r = (0, 1, 0).

A. No spin, racket at rest, v = 2 x_r - 3 n (racket frame (2, 0, -3)):
   v' = ((1 - K_v) 2 + K_v r 0, 0, -e_r (-3)) = (1, 0, 2.4)_r  ->  (2.24, 0, 1.32) world
   w' = (0, K_w r 2, 0)_r = (0, 75, 0)_r                       ->  (0, 75, 0) world
   (the K_w r (n x v) term alone: n x v = (0, 2, 0) world.)
B. Spin in the face w = 100 y_r, v = -3 n, racket at rest (racket frame (0, 0, -3)):
   v' = (K_v r 100, 0, 2.4)_r = (1, 0, 2.4)_r                  ->  (2.24, 0, 1.32) world
   w' = (0, (1 - K_w r^2) 100, 0)_r = (0, 25, 0)_r             ->  (0, 25, 0) world
   (the K_v r (w x n) term alone: w x n = 100 x_r.)
C. Racket moving at u = 5 n = (3, 0, 4); ball v = u + (y_r - 4 n) = (0.6, 1, 0.8), spin
   w = 40 x_r + 10 n = (38, 0, -16) (racket frame v = (0, 1, -4), w = (40, 0, 10)):
   v'_r = (0.5 0 + 0.01 0, 0.5 1 - 0.01 40, 3.2) = (0, 0.1, 3.2)
   w'_r = (0.25 40 - 37.5 1, 0.25 0 + 37.5 0, 10) = (-27.5, 0, 10)
   world: v' = u + 0.1 y_r + 3.2 n = (4.92, 0.1, 6.56), w' = -27.5 x_r + 10 n = (-16, 0, 24.5).
"""

from body_reference import rebound_racket_frame
import numpy as np
import pytest
from tt_prediction.ball import ModelParams, racket_rebound

RUBBER = ModelParams(k_p=1.35e-3, e_r=0.8)
N = np.array([0.6, 0.0, 0.8])

CASES = [   # v_ball, w_ball, racket velocity, v_out, w_out (world), worked out above
    ([-0.2, 0.0, -3.6], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2.24, 0.0, 1.32], [0.0, 75.0, 0.0]),
    ([-1.8, 0.0, -2.4], [0.0, 100.0, 0.0], [0.0, 0.0, 0.0], [2.24, 0.0, 1.32],
     [0.0, 25.0, 0.0]),
    ([0.6, 1.0, 0.8], [38.0, 0.0, -16.0], [3.0, 0.0, 4.0], [4.92, 0.1, 6.56],
     [-16.0, 0.0, 24.5]),
]


def test_the_rubber_gives_round_numbers():
    assert RUBBER.k_p / RUBBER.mass == pytest.approx(0.5)
    inertia = 2.0 / 3.0 * RUBBER.mass * RUBBER.radius ** 2
    assert RUBBER.k_p / inertia * RUBBER.radius == pytest.approx(37.5)


@pytest.mark.parametrize('v, w, u, v_out, w_out', CASES)
def test_tt_racket_rebound_by_hand(v, w, u, v_out, w_out):
    got_v, got_w = racket_rebound(v, w, N, u, RUBBER)
    np.testing.assert_allclose(got_v, v_out, atol=1e-12)
    np.testing.assert_allclose(got_w, w_out, atol=1e-10)


@pytest.mark.parametrize('v, w, u, v_out, w_out', CASES)
def test_reference_rebound_by_hand(v, w, u, v_out, w_out):
    got_v, got_w = rebound_racket_frame(v, w, N, u, k_p=1.35e-3, e_r=0.8)
    np.testing.assert_allclose(got_v, v_out, atol=1e-12)
    np.testing.assert_allclose(got_w, w_out, atol=1e-10)
