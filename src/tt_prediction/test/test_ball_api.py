"""The public ball-model interface (tt_prediction.ball): the Jacobian of eq. 8 against the
definition of a derivative, the RK4 step against the closed-form parabola, the export list."""

import math
import re

import numpy as np
import pytest

from tt_prediction import ball

NOMINAL = ball.ModelParams()


def _numeric_jacobian(s, P, h=1e-6):
    """Central differences of flight_derivative, column by column."""
    J = np.empty((9, 9))
    fp, fm = np.empty(9), np.empty(9)
    for j in range(9):
        sp, sm = s.copy(), s.copy()
        step = h * max(1.0, abs(s[j]))
        sp[j] += step
        sm[j] -= step
        ball.flight_derivative(sp, P, fp)
        ball.flight_derivative(sm, P, fm)
        J[:, j] = (fp - fm) / (2.0 * step)
    return J


EFFECTS_ON = NOMINAL.replace(spin_decay=0.7, wind=(0.4, -0.3, 0.1), c_d_speed_slope=0.02,
                             c_m_spin_ratio_slope=0.3, c_d_spin_ratio_slope=-0.2)


@pytest.mark.parametrize('params', [NOMINAL, EFFECTS_ON], ids=['paper', 'effects'])
def test_flight_jacobian_is_the_derivative_of_eq8(params):
    rng = np.random.default_rng(5)
    P = params.packed()
    for _ in range(20):
        s = np.r_[rng.uniform(-1, 1, 3), rng.uniform(-8, 8, 3), rng.uniform(-400, 400, 3)]
        J = ball.flight_jacobian(s, P, np.empty((9, 9)))
        num = _numeric_jacobian(s, P)
        np.testing.assert_allclose(J, num, rtol=1e-5, atol=1e-6 * np.abs(num).max())


def test_flight_jacobian_spin_block_is_minus_k_m_cross_u():
    # Eq. 8: the spin enters only through (4/3) C_M pi rho r^3 / m (w x v), so
    # d(a)/dw = -k_M [v]x, and the spin is constant (its rows are zero).
    p = NOMINAL
    k_m = 4.0 / 3.0 * p.c_m * math.pi * p.air_density * p.radius ** 3 / p.mass
    v = np.array([-5.0, 0.5, 1.0])
    s = np.r_[0.3, 0.1, 0.3, v, 10.0, -150.0, 30.0]
    J = ball.flight_jacobian(s, p.packed(), np.empty((9, 9)))
    cross_v = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    np.testing.assert_allclose(J[3:6, 6:9], -k_m * cross_v, rtol=1e-12)
    np.testing.assert_array_equal(J[0:3, 3:6], np.eye(3))
    np.testing.assert_array_equal(J[6:9], 0.0)


def test_rk4_step_without_air_is_the_parabola():
    # c_d = c_m = 0: p(h) = p + v h - g h^2/2 e_z exactly (RK4 is exact for this polynomial).
    params = NOMINAL.replace(c_d=0.0, c_m=0.0)
    s = np.r_[1.0, 0.2, 0.3, -5.0, 0.5, 1.2, 100.0, -200.0, 0.0]
    out = np.empty(9)
    work = [np.empty(9) for _ in range(5)]
    h = 0.04
    ball.rk4_step(s, h, params.packed(), out, *work)
    g = params.gravity
    np.testing.assert_allclose(out[:3], s[:3] + s[3:6] * h - [0, 0, 0.5 * g * h * h],
                               atol=1e-14)
    np.testing.assert_allclose(out[3:6], s[3:6] - [0, 0, g * h], atol=1e-14)
    np.testing.assert_array_equal(out[6:9], s[6:9])


def test_the_public_interface_exports_only_public_existing_names():
    assert ball.__all__, 'ball.__all__ is empty'
    for name in ball.__all__:
        assert not name.startswith('_'), name
        assert hasattr(ball, name), name
    for name in ('flight_jacobian', 'rk4_step', 'landing_kernel', 'ModelParams', 'zone_of'):
        assert name in ball.__all__


def test_the_interface_is_documented_with_numpydoc_sections():
    # Functions: Parameters and Returns; classes: Attributes (the ball-model modules; the
    # landing kernel is predict.py's and documented there).
    own = {'tt_prediction.params', 'tt_prediction.model', 'tt_prediction.integrate',
           'tt_prediction.table'}
    for name in ball.__all__:
        obj = getattr(ball, name)
        func = getattr(obj, 'py_func', obj)
        if not callable(obj) or getattr(func, '__module__', '') not in own:
            continue
        doc = obj.__doc__ or ''
        sections = set(re.findall(r'\n\s*(\w+)\n\s*-{3,}\n', doc))
        if isinstance(obj, type):
            assert 'Attributes' in sections, name
        else:
            assert {'Parameters', 'Returns'} <= sections, name


def test_rk4_advance_without_air_is_the_parabola_in_a_new_array():
    # The allocating step (a filter's prediction): same closed form, input untouched.
    params = NOMINAL.replace(c_d=0.0, c_m=0.0)
    s = np.r_[0.5, -0.2, 0.4, -4.0, 1.0, 2.0, 50.0, 0.0, -80.0]
    before = s.copy()
    h = 0.01
    out = ball.rk4_advance(s, h, params.packed())
    g = params.gravity
    np.testing.assert_allclose(out[:3], s[:3] + s[3:6] * h - [0, 0, 0.5 * g * h * h],
                               atol=1e-14)
    np.testing.assert_allclose(out[3:6], s[3:6] - [0, 0, g * h], atol=1e-14)
    np.testing.assert_array_equal(s, before)
