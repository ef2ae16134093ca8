"""Uncertainty of the prediction: sigma points, hit covariance, zone probabilities."""

import numpy as np
import pytest
from tt_prediction.params import ModelParams
from tt_prediction.predict import predict
from tt_prediction.table import HALF_WIDTH, ZONE_WIDTH
from tt_prediction.uncertainty import predict_uncertainty, sigma_points

NOMINAL = ModelParams()
GOOD = np.array([1.6, 0.1, 0.3, -6.0, 0.0, 1.5, 0.0, 100.0, 0.0])


def test_sigma_points_reproduce_mean_and_covariance():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(9, 9))
    cov = a @ a.T
    cov[8] = cov[:, 8] = 0.0                  # a singular one: an exactly known component
    points, weights = sigma_points(GOOD, cov)
    assert np.all(weights > 0.0) and weights.sum() == pytest.approx(1.0)
    mean = weights @ points
    np.testing.assert_allclose(mean, GOOD, atol=1e-12)
    d = points - mean
    np.testing.assert_allclose((weights[:, None] * d).T @ d, cov, atol=1e-9)


def test_bad_covariance_is_an_error():
    with pytest.raises(ValueError, match='positive semi-definite'):
        predict_uncertainty(GOOD, -np.eye(9))
    with pytest.raises(ValueError, match='not finite'):
        predict_uncertainty(GOOD, np.full((9, 9), np.nan))
    # A covariance filled in one triangle only (a user's message): named as not symmetric
    # (it was named not positive semi-definite, from its symmetric part's eigenvalue -0.25).
    lower = np.eye(9) * 1e-6
    lower[1, 0] = 0.5
    with pytest.raises(ValueError, match=r'not symmetric \(largest \|C - C\^T\| 0.5\)'):
        predict_uncertainty(GOOD, lower)
    # Wider than the table, a smash or the spin range: nothing to propagate (its sigma
    # points fly off the table; the hit covariance of those left came out narrower).
    # The spin's limit is the model's 1500 rad/s at the sigma points (sqrt(10) standard
    # deviations out): at 1000 rad/s they spun at 3162 and the hit's spread in y came out
    # 42 mm where 400 gave 212 (a walk-through, 6 Dec 2026).
    for k, words in ((0, r'position standard deviation 1e\+75 m is beyond 1 m'),
                     (4, 'velocity standard deviation 40 m/s'),
                     (8, r'spin standard deviation 2e\+03 rad/s'),
                     (7, r'spin standard deviation 1e\+03 rad/s is beyond 474 rad/s')):
        cov = np.eye(9) * 1e-6
        cov[k, k] = (1e150, 1600.0, (4e6 if k == 8 else 1e6))[k // 3]
        with pytest.raises(ValueError, match=words):
            predict_uncertainty(GOOD, cov)
    # Not positive semi-definite in one block, whatever the other blocks' units: a negative
    # position variance beside a spin variance of 150^2, a correlation of x and y beyond 1.
    for where, value in (((0, 0), -1e-6), ((0, 1), 1e-5)):
        cov = np.diag([1e-6] * 3 + [1e-2] * 3 + [150.0 ** 2] * 3)
        cov[where] = cov[where[::-1]] = value
        with pytest.raises(ValueError, match='not positive semi-definite'):
            predict_uncertainty(GOOD, cov)
    cov = np.eye(9) * 1e-6
    cov[0, 0] = 0.99 ** 2                                   # within: propagated
    assert predict_uncertainty(GOOD, cov).zone_probabilities.sum() == pytest.approx(1.0)


def test_known_state_gives_a_certain_zone_and_no_spread():
    nominal = predict(GOOD, NOMINAL)
    u = predict_uncertainty(GOOD, np.zeros(81), NOMINAL)
    assert u.zone_half == -1
    assert u.zone_probabilities[nominal.bounce.zone] == pytest.approx(1.0, abs=1e-12)
    assert u.zone_probabilities.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(u.hit_covariance, 0.0, atol=1e-20)
    assert u.hit_time_std == pytest.approx(0.0, abs=1e-12) and u.hit_fraction == 1.0


def test_a_sideways_offset_carries_over_to_the_hit_point_unchanged():
    # Nothing in the model depends on y: an offset dy moves the whole flight by dy, so the
    # hit point's y variance equals the state's and its x and z are unaffected.
    sigma = 0.01
    cov = np.zeros((9, 9))
    cov[1, 1] = sigma ** 2
    u = predict_uncertainty(GOOD, cov, NOMINAL)
    assert u.hit_covariance[1, 1] == pytest.approx(sigma ** 2, rel=1e-6)
    assert abs(u.hit_covariance[0, 0]) < 1e-18 and abs(u.hit_covariance[2, 2]) < 1e-18
    assert u.hit_time_std < 1e-9


def test_a_bounce_on_a_zone_border_splits_the_probability_between_the_two_areas():
    nominal = predict(GOOD, NOMINAL)
    border = HALF_WIDTH - ZONE_WIDTH                  # between columns 0 and 1
    state = GOOD.copy()
    state[1] += border - nominal.bounce.p[1]          # vy = 0: y stays put
    zone = predict(state, NOMINAL).bounce.zone
    row = (zone - 1) // 3
    cov = np.diag([1e-6, 4e-4, 1e-6, 1e-4, 1e-6, 1e-4, 1.0, 1.0, 1.0])
    u = predict_uncertainty(state, cov, NOMINAL)
    left, right = u.zone_probabilities[3 * row + 1], u.zone_probabilities[3 * row + 2]
    assert left == pytest.approx(0.5, abs=0.06) and right == pytest.approx(0.5, abs=0.06)
    assert u.zone_probabilities.sum() == pytest.approx(1.0)


def test_a_wide_spread_puts_probability_off_the_table():
    cov = np.diag([1e-4, 0.3, 1e-4, 1.0, 1.0, 1.0, 100.0, 100.0, 100.0])
    u = predict_uncertainty(GOOD, cov, NOMINAL)
    assert u.zone_probabilities[0] > 0.05
    assert u.zone_probabilities.sum() == pytest.approx(1.0)
    assert np.all(u.zone_probabilities >= 0.0)
    assert np.all(np.linalg.eigvalsh(u.hit_covariance) >= -1e-15)
