"""Physics of the ball model (MODEL.md) through the predictor: each expectation is derived
from the equations or the paper's observations, not from the code's output."""

import math

import numpy as np
import pytest
from tt_prediction.model import racket_rebound, table_rebound
from tt_prediction.params import ModelParams
from tt_prediction.predict import predict
from tt_prediction.table import (
    HALF_LENGTH,
    HALF_WIDTH,
    ZONE_LENGTH,
    ZONE_WIDTH,
    zone_bounds,
    zone_of,
)

NOMINAL = ModelParams()
RPM = 2.0 * math.pi / 60.0


def energy(v, w, params=NOMINAL):
    """Kinetic energy of the ball, translation plus rotation (thin shell), J."""
    return 0.5 * params.mass * v @ v + 0.5 * params.inertia * w @ w


def test_free_flight_without_air_is_the_parabola():
    params = NOMINAL.replace(c_d=0.0, c_m=0.0)
    p0 = np.array([1.2, 0.1, 0.35])
    v0 = np.array([-5.0, 0.4, 0.8])
    g, r = params.gravity, params.radius
    # z(t) = z0 + vz t - g t^2 / 2 = r, the later root.
    t_b = (v0[2] + math.sqrt(v0[2] ** 2 + 2.0 * g * (p0[2] - r))) / g
    pred = predict(np.r_[p0, v0, 300.0, -200.0, 50.0], params, t0=2.0)
    assert pred.status == 'ok'
    assert pred.bounce.t == pytest.approx(2.0 + t_b, abs=1e-9)
    np.testing.assert_allclose(pred.bounce.p, [p0[0] + v0[0] * t_b, p0[1] + v0[1] * t_b, r],
                               atol=1e-8)
    # After the bounce the spin changes the velocity (eqs. 1-6) but the flight is a parabola
    # again: the plane crossing follows from the post-bounce velocity of table_rebound.
    v_in = np.array([v0[0], v0[1], v0[2] - g * t_b])
    v1, _ = table_rebound(v_in, np.array([300.0, -200.0, 50.0]), params)
    t_h = (-1.5 - pred.bounce.p[0]) / v1[0]
    assert pred.hit.t == pytest.approx(pred.bounce.t + t_h, abs=1e-9)
    np.testing.assert_allclose(
        pred.hit.p, [-1.5, pred.bounce.p[1] + v1[1] * t_h, r + v1[2] * t_h - g * t_h ** 2 / 2],
        atol=1e-8)



@pytest.mark.parametrize('rate', [500.0, 1000.0])
def test_a_flight_sampled_at_jittered_stamps_is_the_parabola_at_every_one(rate):
    # A lab's stamps at 500 Hz-1 kHz with 0.2 ms of jitter: the state at each is the no-air
    # parabola's. (A step to one stamp landing an ulp past it stopped the flight there: every
    # later sample NaN, which tt-identify fitted as a missing residual.)
    from tt_prediction.integrate import rollout
    params = NOMINAL.replace(c_d=0.0, c_m=0.0)
    p0, v0 = np.array([1.2, 0.1, 0.4]), np.array([-5.0, 0.2, 1.5])
    rng = np.random.default_rng(7)
    # 0.001557 + (0.003629 - 0.001557) is 0.0036290000000000003: the first set's stamps.
    for k in range(300):
        t = np.sort(np.arange(1, 60) / rate + rng.normal(0.0, 2e-4, 59))
        t = np.round(t[t > 0.0], 6)     # stamps as a CSV writes them
        if k == 0:
            t = np.r_[0.001557, 0.003629, t[t > 0.004]]
        _, samples = rollout(np.r_[p0, v0, 0.0, 0.0, 0.0], params, max_bounces=1,
                             sample_times=t)
        z = p0[2] + v0[2] * t - 0.5 * params.gravity * t ** 2
        np.testing.assert_allclose(samples[:, 2], z, atol=1e-9)
        np.testing.assert_allclose(samples[:, 0], p0[0] + v0[0] * t, atol=1e-9)

def test_a_table_bounce_never_adds_energy():
    rng = np.random.default_rng(3)
    for _ in range(2000):
        v = rng.uniform(-10.0, 10.0, 3)
        v[2] = -abs(v[2]) - 0.1
        w = rng.uniform(-900.0, 900.0, 3)
        v1, w1 = table_rebound(v, w, NOMINAL)
        assert energy(v1, w1) <= energy(v, w) * (1.0 + 1e-12)


def test_the_rolling_sliding_switch_is_continuous():
    # nu_s = 1 - 5/2 mu (1 + e_t) |v_z| / |v_T| changes sign at |v_z| = |v_T| / (2.5 mu (1+e_t)).
    w = np.array([0.0, 150.0, 0.0])
    v_t = 4.0 - NOMINAL.radius * w[1]           # v_x - r w_y
    vz_switch = v_t / (2.5 * NOMINAL.mu * (1.0 + NOMINAL.e_t))
    eps = 1e-9
    below = table_rebound(np.array([4.0, 0.0, -(vz_switch - eps)]), w, NOMINAL)  # sliding
    above = table_rebound(np.array([4.0, 0.0, -(vz_switch + eps)]), w, NOMINAL)  # rolling
    np.testing.assert_allclose(below[0], above[0], atol=1e-6)
    np.testing.assert_allclose(below[1], above[1], atol=1e-4)
    # Rolling: the contact point leaves without slip, v_x' - r w_y' = 0.
    assert above[0][0] - NOMINAL.radius * above[1][1] == pytest.approx(0.0, abs=1e-9)


def _bounce_x(w_y):
    state = [1.6, 0.0, 0.3, -6.0, 0.0, 1.5, 0.0, w_y, 0.0]
    pred = predict(state, NOMINAL)
    assert pred.bounce is not None, pred.reason
    return pred.bounce.p[0]


def test_topspin_shortens_and_backspin_lengthens_the_flight():
    # For a ball moving along -x, topspin is w_y < 0: the Magnus force w x v points down.
    w = 3000.0 * RPM
    assert np.cross([0.0, -w, 0.0], [-6.0, 0.0, 0.0])[2] < 0.0
    top, none, back = _bounce_x(-w), _bounce_x(0.0), _bounce_x(w)
    assert top > none + 0.05      # lands nearer the net (x less negative): shorter
    assert back < none - 0.05


def test_the_rubber_reverses_tangential_spin_for_the_nominal_k_p():
    # Eq. 7: w_t' = (1 - K_w r^2) w_t + K_w r (n x v); K_w r^2 = 1.5 k_p / m > 1 nominally.
    factor = 1.0 - 1.5 * NOMINAL.k_p / NOMINAL.mass
    assert factor < 0.0
    normal = np.array([1.0, 0.0, 0.0])           # racket at the robot's end, face to +x
    v = np.array([-5.0, 0.0, 0.0])                # head-on: no tangential velocity
    w = np.array([0.0, 200.0, 0.0])               # tangential spin
    v1, w1 = racket_rebound(v, w, normal, np.zeros(3), NOMINAL)
    assert w1[1] == pytest.approx(factor * w[1], rel=1e-12)
    assert w1[1] * w[1] < 0.0
    assert v1[0] == pytest.approx(NOMINAL.e_r * 5.0, rel=1e-12)


@pytest.mark.parametrize('half', [1, -1])
def test_zone_boundaries_follow_the_9_area_criterion(half):
    eps = 1e-6
    for row in range(3):
        for col in range(3):
            zone = 3 * row + col + 1
            x0, x1, y0, y1 = zone_bounds(zone, half)
            assert x1 - x0 == pytest.approx(ZONE_LENGTH)
            assert y1 - y0 == pytest.approx(ZONE_WIDTH)
            # Row 0 next to the net, column 0 on the +y side.
            assert min(abs(x0), abs(x1)) == pytest.approx(row * ZONE_LENGTH)
            assert y1 == pytest.approx(HALF_WIDTH - col * ZONE_WIDTH)
            for x in (x0 + eps, x1 - eps):
                for y in (y0 + eps, y1 - eps):
                    assert zone_of(x, y) == (zone, half)
    assert zone_of(half * (HALF_LENGTH + eps), 0.0) == (0, 0)
    assert zone_of(half * 0.5, HALF_WIDTH + eps) == (0, 0)


def test_predicted_bounce_zone_is_the_area_under_the_contact():
    rng = np.random.default_rng(5)
    for _ in range(30):
        state = [1.5, rng.uniform(-0.4, 0.4), 0.3, rng.uniform(-7.0, -5.0),
                 rng.uniform(-1.0, 1.0), 1.2, 0.0, rng.uniform(-200, 200), 0.0]
        pred = predict(state, NOMINAL)
        if pred.bounce is None:
            continue
        x, y = pred.bounce.p[:2]
        row = int(abs(x) // ZONE_LENGTH)
        col = int((HALF_WIDTH - y) // ZONE_WIDTH)
        assert pred.bounce.zone == 3 * row + col + 1
        assert pred.bounce.half == (1 if x > 0 else -1)


def test_fig9_aerodynamics_moves_the_landing_by_tenths_of_a_metre_more_for_topspin():
    """The paper's Fig. 9 balls: -6.2 m/s with -3400 rpm (topspin for a ball along -x) and
    -6.5 m/s with +3400 rpm (backspin) about y; first contact with and without air."""
    no_air = NOMINAL.replace(c_d=0.0, c_m=0.0)
    shift = {}
    for name, vx, w_y in (('top', -6.2, -3400 * RPM), ('back', -6.5, 3400 * RPM)):
        state = [1.6, 0.0, 0.3, vx, 0.0, 1.5, 0.0, w_y, 0.0]
        with_air, without = predict(state, NOMINAL), predict(state, no_air)
        assert with_air.bounce is not None and without.bounce is not None
        shift[name] = abs(with_air.bounce.p[0] - without.bounce.p[0])
    assert 0.1 <= shift['back'] < 1.0
    assert 0.1 <= shift['top'] < 1.0
    assert shift['top'] > shift['back']
