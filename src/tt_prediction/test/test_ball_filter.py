"""The ball filter: its Jacobians against the model, the bounce as a spin measurement, the
consistency of its covariance (NEES against chi-square bounds) and stream handling."""

import copy

import numpy as np
import pytest
from scipy.stats import chi2, norm
from tt_prediction.ball import ModelParams, rollout, table_rebound_inplace
from tt_prediction.ball_filter import (
    BallFilter,
    FilterConfig,
    TrackFilter,
    estimate_measurement_noise,
    rebound_jacobian,
    smooth,
    spin_likelihood_per_axis,
    spin_outlier_log_odds,
    velocity_frame,
)
from tt_prediction.predict import predict

EFFECTS = ModelParams(c_d_speed_slope=0.02, c_m_spin_ratio_slope=0.05,
                      c_d_spin_ratio_slope=0.08, spin_decay=0.3, wind=(0.2, -0.1, 0.05),
                      e_t_speed_slope=-0.1, mu_spin_slope=2e-4)
REBOUND_EFFECTS = ModelParams(e_t_speed_slope=-0.1, mu_spin_slope=2e-4, e_t_spin_slope=0.01,
                              mu_slip_slope=0.02, e_t_tangential=0.3, e_t_edge=-0.08)
# An incoming ball with top and side spin: bounces on the robot's half, crosses x = -1.2.
INCOMING = np.array([1.3, 0.1, 0.3, -5.5, -0.2, 1.0, 20.0, -150.0, 40.0])


def _numeric(fun, s, eps):
    J = np.empty((9, 9))
    for j in range(9):
        a, b = s.copy(), s.copy()
        a[j] += eps[j]
        b[j] -= eps[j]
        J[:, j] = (fun(a) - fun(b)) / (2 * eps[j])
    return J


@pytest.mark.parametrize('params', [ModelParams(), EFFECTS, REBOUND_EFFECTS])
@pytest.mark.parametrize('spin_y', [-150.0, 0.0, 400.0])
@pytest.mark.parametrize('place', [(-0.5, 0.1), (-1.31, 0.1), (-0.9, -0.72), (1.31, 0.1),
                                   (0.9, 0.72)],
                         ids=['middle', 'near the end line', 'near a side line',
                              'near the far end line', 'near the other side line'])
def test_rebound_jacobian_is_the_derivative_of_eqs_1_to_6(params, spin_y, place):
    P = params.packed()
    s = np.array([*place, 0.02, -4.0, 0.5, -3.0, 25.0, spin_y, 50.0])

    def rebound(x):
        y = x.copy()
        table_rebound_inplace(y, P)
        return y

    J = np.empty((9, 9))
    rebound_jacobian(s, P, J)
    eps = np.array([1e-4] * 3 + [1e-6] * 3 + [1e-4] * 3)
    assert np.allclose(J, _numeric(rebound, s, eps), rtol=1e-5, atol=1e-6)


def _measured(state, times, noise, rng, params=None):
    _, samples = rollout(state, params or ModelParams(), sample_times=times,
                         stop_at_plane=False, stop_at_net=False, max_bounces=2,
                         t_max=times[-1] + 1e-6)
    return samples, samples[:, :3] + rng.normal(0.0, noise, (len(times), 3))


def test_the_bounce_measures_the_spin_flight_cannot_see():
    """In flight only the spin across v is observed (Magnus); eqs. 1-2 turn r w_x into v_y at
    the contact, so post-bounce samples pin the spin along v (here mostly w_x)."""
    rng = np.random.default_rng(3)
    times = np.arange(0.0, 0.75, 1.0 / 180.0)
    truth, z = _measured(INCOMING, times, 1e-3, rng)
    events, _ = rollout(INCOMING, ModelParams(), stop_at_plane=False, max_bounces=1)
    t_bounce = events[-1].t
    cfg = FilterConfig(position_noise=1e-3, accel_noise=0.01, spin_noise=0.1, spin_prior=150.0)
    tf = TrackFilter(config=cfg)
    before = after = None
    for t, p in zip(times, z, strict=True):
        tf.add(t, p)
        if before is None and t > t_bounce - 0.01:
            before = tf.filter.P[6, 6]
        if t > t_bounce + 0.08:
            after = tf.filter.P[6, 6]
            est, true = tf.filter.x[6], truth[np.searchsorted(times, t), 6]
            break
    assert tf.filter.bounces == 1 and tf.robot_bounced
    assert np.sqrt(before) > 0.5 * 150.0            # along v: still close to its prior
    assert np.sqrt(after) < 0.5 * np.sqrt(before)   # the bounce measured it
    assert abs(est - true) < 3.0 * np.sqrt(after)


def _with_rebound_noise(s0, times, cfg, rng):
    """True states at ``times`` of a ball whose rebound has the filter's rebound noise:
    eqs. 1-6 plus N(0, bounce_velocity_noise^2) on each velocity and N(0, bounce_spin_noise^2)
    on each spin component. Returns (states (n, 9), bounce time)."""
    params = ModelParams()
    events, before = rollout(s0, params, sample_times=times, stop_at_plane=False,
                             stop_at_net=False, max_bounces=1, t_max=times[-1] + 1e-6)
    b = events[-1]
    after = b.after.copy()
    after[3:6] += rng.normal(0.0, cfg.bounce_velocity_noise, 3)
    after[6:9] += rng.normal(0.0, cfg.bounce_spin_noise, 3)
    later = times > b.t
    _, rest = rollout(after, params, t0=b.t, sample_times=times[later], stop_at_plane=False,
                      stop_at_net=False, max_bounces=1, t_max=times[-1] + 1e-6)
    states = before.copy()
    states[later] = rest
    return states, b.t


@pytest.mark.parametrize('transform', ['linear', 'unscented'])
@pytest.mark.parametrize('phase', ['flight', 'after_bounce'])
def test_covariance_is_consistent_nees_within_chi_square_bounds(phase, transform):
    """Monte Carlo with the filter's own statistics: spin drawn from its prior, positions with
    its noise, the rebound perturbed by its rebound noise. The mean NEES of the 9-dim state
    over N runs must lie in the two-sided 99 % interval chi-square(9 N) / N, in flight 30 ms
    before the bounce and 60 ms after it, with either transform of the rebound (eqs. 1-6)."""
    rng = np.random.default_rng(7)
    prior, noise, n = 60.0, 1e-3, 40
    # The truth has no unmodelled acceleration: the filter's is next to none at every speed.
    cfg = FilterConfig(position_noise=noise, accel_noise=1e-3, accel_noise_speed=0.0,
                       spin_noise=0.05, spin_prior=prior, start_velocity_noise=0.02,
                       bounce_transform=transform)
    times = np.arange(0.0, 0.5, 1.0 / 180.0)
    values = []
    for _ in range(n):
        s0 = INCOMING.copy()
        s0[6:] = rng.normal(0.0, prior, 3)
        truth, tb = _with_rebound_noise(s0, times, cfg, rng)
        z = truth[:, :3] + rng.normal(0.0, noise, (len(times), 3))
        mark = tb - 0.03 if phase == 'flight' else tb + 0.06
        tf = TrackFilter(config=cfg)
        for i, (t, p) in enumerate(zip(times, z, strict=True)):
            tf.add(t, p)
            if t >= mark:
                e = tf.filter.x - truth[i]
                values.append(float(e @ np.linalg.solve(tf.filter.P, e)))
                break
    assert len(values) == n
    lo, hi = chi2.ppf([0.005, 0.995], 9 * n) / n
    assert lo < np.mean(values) < hi, (phase, np.mean(values), lo, hi)


def _stream():
    rng = np.random.default_rng(11)
    times = np.arange(0.0, 0.8, 1.0 / 180.0)
    truth, z = _measured(INCOMING, times, 1e-3, rng)
    return times, truth, z


def test_stream_with_spikes_gaps_duplicates_and_nan_keeps_tracking():
    times, truth, z = _stream()
    t, p = times.copy(), z.copy()
    p[[30, 31, 70]] += [0.08, 0.0, 0.05]                 # spikes
    gap = (t > 0.2) & (t < 0.25)                          # 50 ms without data
    p[[10, 50]] = np.nan                                 # NaN rows
    keep = ~gap
    t, p, tr = t[keep], p[keep], truth[keep]
    t = np.insert(t, 20, t[20])                           # a duplicate stamp
    p = np.insert(p, 20, p[20], axis=0)
    tr = np.insert(tr, 20, tr[20], axis=0)
    tf = TrackFilter(config=FilterConfig(position_noise=1e-3))
    statuses = [tf.add(ti, pi) for ti, pi in zip(t, p, strict=True)]
    assert statuses[21] == TrackFilter.SKIPPED            # the duplicate
    assert statuses[10] == TrackFilter.COASTED            # the NaN row
    assert TrackFilter.REJECTED in statuses[29:33]        # the spikes are gated
    assert np.linalg.norm(tf.filter.x[:3] - tr[-1, :3]) < 5e-3
    assert tf.filter.t == pytest.approx(t[-1])


def test_a_samples_covariance_is_its_position_noise_and_along_v_its_stamps_jitter():
    """FilterConfig.sample_cov (the compiled _sample_cov the fused step uses too) against
    its definition: a stamp off by dt moves the sample by v dt, so R = sigma^2 I + tau^2 v
    v^T; across v only sigma^2, along it sigma^2 + tau^2 |v|^2."""
    sigma, tau = 1.5e-3, 4e-4
    v = np.array([-6.0, 0.8, 2.5])
    R = FilterConfig(position_noise=sigma, stamp_noise=tau).sample_cov(v)
    np.testing.assert_allclose(R, sigma ** 2 * np.eye(3) + tau ** 2 * np.outer(v, v),
                               rtol=1e-12, atol=0.0)
    u = v / np.linalg.norm(v)
    across = np.cross(u, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    assert u @ R @ u == pytest.approx(sigma ** 2 + tau ** 2 * (v @ v), rel=1e-12)
    assert across @ R @ across == pytest.approx(sigma ** 2, rel=1e-12)


@pytest.mark.parametrize('speed', [0.5, 3.0, 8.0])
@pytest.mark.parametrize('ref_speed', [3.0, 0.0])
def test_the_unmodelled_acceleration_grows_as_the_aerodynamic_force(speed, ref_speed):
    """The process noise is a white acceleration whose density grows as the drag and Magnus
    forces do (|v|^2 in amplitude): accel_noise^2 (1 + (|v| / accel_noise_speed)^4) in
    variance, the same at every speed with accel_noise_speed 0. Over one step h from a state
    known exactly, each velocity component's variance is that density times h and each
    position's that times h^3 / 3 (the integral of a white acceleration)."""
    q, h = 0.05, 2e-3
    f = BallFilter(ModelParams(), FilterConfig(accel_noise=q, spin_noise=0.0,
                                               accel_noise_speed=ref_speed))
    v = speed * np.array([-0.8, 0.36, 0.48])
    f.start(0.0, [0.5, 0.1, 0.5], v, np.zeros((3, 3)), np.zeros((3, 3)), spin=[0.0, 50.0, 0.0],
            spin_cov=np.zeros((3, 3)))
    f.P = np.zeros((9, 9))
    f.predict(h)
    density = q ** 2 * (1.0 + ((speed / ref_speed) ** 4 if ref_speed else 0.0))
    np.testing.assert_allclose(np.diag(f.P)[3:6], density * h, rtol=1e-9)
    np.testing.assert_allclose(np.diag(f.P)[:3], density * h ** 3 / 3.0, rtol=1e-9)


def test_the_fused_step_is_predict_then_update_with_the_samples_covariance():
    """BallFilter.predict_fuse (one compiled call) gives what predict(t) and then update(z,
    config.sample_cov(v)) give, bit for bit, through the bounce and for a spike the gate
    refuses (the filter left predicted, the kink tried by rebounce from it)."""
    times, _, z = _stream()
    z[40] += [0.0, 0.05, 0.0]                          # a spike: refused by both
    cfg = FilterConfig(position_noise=1e-3, stamp_noise=3e-4)
    plain, fused = BallFilter(config=cfg), BallFilter(config=cfg)
    for f in (plain, fused):
        f.start(times[0], z[0], [-5.5, -0.2, 1.0], np.eye(3) * 1e-6, np.eye(3) * 0.1)
    accepted = []
    for ti, zi in zip(times[1:], z[1:], strict=True):
        plain.predict(ti)
        ok = plain.update(zi, cfg.sample_cov(plain.x[3:6]), rebounce=True)
        R, done = fused.predict_fuse(ti, zi)
        assert np.array_equal(R, cfg.sample_cov(fused.x[3:6]))
        assert fused.update(zi, R, rebounce=True, fused=done) == ok
        assert np.array_equal(fused.x, plain.x) and np.array_equal(fused.P, plain.P)
        assert fused.bounces == plain.bounces and fused.last_bounce == plain.last_bounce
        accepted.append(ok)
    assert plain.bounces == 1 and not accepted[39] and sum(accepted) == len(accepted) - 1


def test_out_of_order_stamp_is_skipped():
    times, _, z = _stream()
    tf = TrackFilter(config=FilterConfig(position_noise=1e-3))
    for t, p in zip(times[:20], z[:20], strict=True):
        tf.add(t, p)
    assert tf.add(times[5], z[5]) == TrackFilter.SKIPPED


def test_restart_after_a_racket_like_turn():
    """The velocity turned by a hit: the gate rejects, then the filter restarts from the data
    and follows the new flight."""
    rng = np.random.default_rng(5)
    times = np.arange(0.0, 0.25, 1.0 / 180.0)
    _, z1 = _measured(INCOMING, times, 1e-3, rng)
    s = INCOMING.copy()
    s[:3] = z1[-1]
    s[3:6] = [5.0, 0.3, 2.0]
    t2 = times[-1] + np.arange(1, 40) / 180.0
    truth2, z2 = _measured(s, np.concatenate([[times[-1]], t2]), 1e-3, rng)
    tf = TrackFilter(config=FilterConfig(position_noise=1e-3))
    for t, p in zip(np.concatenate([times, t2]), np.concatenate([z1, z2[1:]]), strict=True):
        tf.add(t, p)
    assert np.linalg.norm(tf.filter.x[3:6] - truth2[-1, 3:6]) < 0.3
    assert not tf.robot_bounced                              # moving away from the robot


def test_position_noise_estimate_recovers_the_noise():
    rng = np.random.default_rng(2)
    times = np.arange(0.0, 0.4, 1.0 / 180.0)
    tracks = [_measured(INCOMING, times, 1.5e-3, rng)[1] for _ in range(10)]
    est, _ = estimate_measurement_noise((times, p) for p in tracks)
    assert est == pytest.approx(1.5e-3, rel=0.15)


def test_position_noise_estimate_ignores_outliers():
    """5 % of the samples moved 1-3 cm (a detector's false match): the estimate is the noise
    of the others, within 15 %."""
    rng = np.random.default_rng(3)
    times = np.arange(0.0, 0.4, 1.0 / 180.0)
    tracks = []
    for _ in range(10):
        p = _measured(INCOMING, times, 6e-4, rng)[1]
        moved = rng.random(len(times)) < 0.05
        direction = rng.normal(size=(moved.sum(), 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        p[moved] += direction * rng.uniform(0.01, 0.03, (moved.sum(), 1))
        tracks.append((times, p))
    est, _ = estimate_measurement_noise(tracks)
    assert est == pytest.approx(6e-4, rel=0.15)


def test_measurement_noise_estimate_separates_stamp_jitter():
    """Positions sampled at jittered times but stamped at the nominal ones: the error along
    the velocity is v dt, across it only the position noise."""
    rng = np.random.default_rng(6)
    nominal = np.arange(0.0, 0.3, 1.0 / 180.0)
    tracks = []
    for _ in range(20):
        true_t = nominal + 0.002 + rng.normal(0.0, 4e-4, len(nominal))
        _, s = rollout(INCOMING, ModelParams(), sample_times=np.sort(true_t),
                       stop_at_plane=False, stop_at_net=False, max_bounces=2, t_max=0.31)
        tracks.append((nominal, s[:, :3] + rng.normal(0.0, 6e-4, (len(nominal), 3))))
    assert all(np.isfinite(p).all() for _, p in tracks)
    sigma_p, sigma_t = estimate_measurement_noise(tracks)
    assert sigma_p == pytest.approx(6e-4, rel=0.15)
    assert sigma_t == pytest.approx(4e-4, rel=0.2)


def test_filter_state_predicts_the_hit_the_model_predicts():
    """Fed the model's own flight, the filter's state 50 ms after the bounce (spin measured by
    it) gives the predictor's hit to < 2 mm."""
    rng = np.random.default_rng(4)
    times = np.arange(0.0, 0.8, 1.0 / 180.0)
    _, z = _measured(INCOMING, times, 1e-3, rng)
    ref = predict(INCOMING, hit_plane_x=-1.2)
    tf = TrackFilter(config=FilterConfig(position_noise=1e-3, accel_noise=0.01))
    for t, p in zip(times, z, strict=True):
        if t > ref.bounce.t + 0.05:
            break
        tf.add(t, p)
    pred = predict(tf.filter.x, t0=tf.filter.t, hit_plane_x=-1.2, bounced=True)
    assert pred.status == 'ok'
    assert np.linalg.norm(pred.hit.p - ref.hit.p) < 2e-3


def test_an_earlier_state_is_the_flight_carried_back_and_none_across_a_bounce():
    """earlier_state carries the estimate back along eq. 8: the model's forward rollout
    (its own integrator) at the earlier time, within 0.05 mm and 1 mm/s; its covariance,
    carried forward again by the flight with no process noise, is the one it came from
    (within 1 % of each entry's sigmas: the flight map is of second order per step). A
    time before a table contact has no such state (the rebound is not undone)."""
    params = ModelParams()
    state = np.array([0.9, 0.1, 0.25, -5.0, 0.3, -0.5, 30.0, -200.0, 10.0])
    times = np.arange(0.0, 0.3, 0.01)
    _, flight = rollout(state, params, sample_times=times, stop_at_plane=False,
                        stop_at_net=False, t_max=times[-1] + 1e-6)
    bounce = times[np.argmin(flight[:, 2])]
    assert 0.05 < bounce < 0.25 and flight[-1, 5] > 0.0      # one contact, then up again
    after = int(np.searchsorted(times, bounce)) + 2
    f = BallFilter(params, FilterConfig(accel_noise=0.0, spin_noise=0.0))
    P0 = np.diag([1e-6] * 3 + [1e-2] * 3 + [1e2] * 3)
    f.start(times[after], flight[after, :3], flight[after, 3:6], P0[:3, :3], P0[3:6, 3:6],
            spin=flight[after, 6:], spin_cov=P0[6:, 6:])
    f.P = P0
    f.predict(times[-1])
    x, C = f.earlier_state(times[after + 3])
    assert np.allclose(x[:3], flight[after + 3, :3], atol=5e-5)
    assert np.allclose(x[3:6], flight[after + 3, 3:6], atol=1e-3)
    g = BallFilter(params, FilterConfig(accel_noise=0.0, spin_noise=0.0))
    g.start(times[after + 3], x[:3], x[3:6], C[:3, :3], C[3:6, 3:6], spin=x[6:],
            spin_cov=C[6:, 6:])
    g.P = C
    g.predict(times[-1])
    scale = np.sqrt(np.outer(np.diag(f.P), np.diag(f.P)))      # each entry against its sigmas
    assert np.all(np.abs(g.P - f.P) <= 0.01 * scale)
    assert f.earlier_state(times[after]) is not None
    before = BallFilter(params)
    before.start(0.0, state[:3], state[3:6], P0[:3, :3], P0[3:6, 3:6], spin=state[6:])
    before.predict(times[-1])
    assert before.bounces == 1
    assert before.earlier_state(bounce - 0.02) is None
    assert before.earlier_state(times[-1] + 0.01) is None


def _run_filter(params, cfg, times, z, R, start_cov, spin=None):
    """A BallFilter started at times[0] on z[0] with the velocity of the first two samples,
    then updated with every sample; returns smooth()'s steps."""
    f = BallFilter(params, cfg)
    v0 = (z[1] - z[0]) / (times[1] - times[0])
    f.start(times[0], z[0], v0, start_cov[:3, :3], start_cov[3:6, 3:6], spin=spin,
            spin_cov=start_cov[6:, 6:])
    steps = [(times[0], f.x.copy(), f.P.copy(), f.contact_z)]
    for t, p in zip(times[1:], z[1:], strict=True):
        f.predict(t)
        assert f.update(p, R, rebounce=True)
        steps.append((t, f.x.copy(), f.P.copy(), f.contact_z))
    return steps


def test_smoothing_a_ballistic_flight_is_the_batch_least_squares_fit():
    """Without air (C_D and C_M terms negligible) and without process noise the flight is
    linear, p(t) = p0 + v0 t + g t^2 / 2, and the fixed-interval smoother must give, at every
    sample, what a batch weighted least-squares fit of (p0, v0) to all samples and the
    start's prior gives (normal equations, written here from the model): the same mean and
    covariance."""
    rng = np.random.default_rng(5)
    params = ModelParams(air_density=1e-12)
    cfg = FilterConfig(accel_noise=0.0, spin_noise=0.0, gate=1e12, robust=1e12)
    g = np.array([0.0, 0.0, -params.gravity])
    times = np.arange(0.0, 0.3, 1.0 / 150.0)
    p0, v0 = np.array([1.2, 0.1, 0.3]), np.array([-6.0, 0.4, 1.5])
    truth = p0 + np.outer(times, v0) + 0.5 * np.outer(times ** 2, g)
    R = np.diag([1e-6, 4e-6, 2e-6])
    z = truth + rng.multivariate_normal(np.zeros(3), R, len(times))
    start_cov = np.diag([1e-4] * 3 + [0.5] * 3 + [100.0] * 3)
    steps = _run_filter(params, cfg, times, z, R, start_cov)
    smoothed = smooth(steps, params, cfg)
    # Batch: unknown y = (p, v) at times[0], prior N(steps[0] mean, its covariance).
    y0, Y0 = steps[0][1][:6], steps[0][2][:6, :6]
    info, vec = np.linalg.inv(Y0), np.linalg.solve(Y0, y0)
    Ri = np.linalg.inv(R)
    for t, p in zip(times[1:], z[1:], strict=True):      # the start's sample is its prior
        H = np.hstack([np.eye(3), np.eye(3) * (t - times[0])])
        info += H.T @ Ri @ H
        vec += H.T @ Ri @ (p - 0.5 * g * (t - times[0]) ** 2)
    cov = np.linalg.inv(info)
    y = cov @ vec
    for (t, *_), (x, C) in zip(steps, smoothed, strict=True):
        Phi = np.block([[np.eye(3), np.eye(3) * (t - times[0])], [np.zeros((3, 3)), np.eye(3)]])
        mean = Phi @ y + np.concatenate([0.5 * g * (t - times[0]) ** 2, g * (t - times[0])])
        var = Phi @ cov @ Phi.T
        sd = np.sqrt(np.diag(var))
        assert np.all(np.abs(x[:6] - mean) <= 1e-5 * sd), (t, x[:6] - mean, sd)
        assert np.all(np.abs(C[:6, :6] - var) <= 1e-5 * np.outer(sd, sd))
    # The last sample's smoothed state is the filter's own.
    assert np.array_equal(smoothed[-1][0], steps[-1][1])


def test_smoothing_through_a_bounce_uses_the_later_samples_and_stays_consistent():
    """A spinning ball through a bounce, the truth drawn with the filter's own statistics (as
    in the NEES test above): the smoothed states, given the samples after them too, must be
    consistent (mean NEES over the runs within the two-sided 99 % chi-square(9 N) / N
    interval) 30 ms before the bounce and 60 ms after it, and their velocity error from 50
    ms after the start at most half the filter's (medians over the runs)."""
    rng = np.random.default_rng(9)
    prior, noise, n = 60.0, 1e-3, 40
    cfg = FilterConfig(position_noise=noise, accel_noise=1e-3, spin_noise=0.05,
                       spin_prior=prior)
    times = np.arange(0.0, 0.5, 1.0 / 180.0)
    R = np.eye(3) * noise ** 2
    start_cov = np.diag([noise ** 2] * 3 + [2 * noise ** 2 * 180.0 ** 2 + 0.02 ** 2] * 3
                        + [prior ** 2] * 3)
    nees = {'flight': [], 'after_bounce': []}
    filtered, smoothed_err = [], []
    for _ in range(n):
        s0 = INCOMING.copy()
        s0[6:] = rng.normal(0.0, prior, 3)
        truth, tb = _with_rebound_noise(s0, times, cfg, rng)
        z = truth[:, :3] + rng.normal(0.0, noise, (len(times), 3))
        steps = _run_filter(ModelParams(), cfg, times, z, R, start_cov, spin=np.zeros(3))
        states = smooth(steps, ModelParams(), cfg)
        for phase, mark in (('flight', tb - 0.03), ('after_bounce', tb + 0.06)):
            i = int(np.searchsorted(times, mark))
            e = states[i][0] - truth[i]
            nees[phase].append(float(e @ np.linalg.solve(states[i][1], e)))
        judged = times >= 0.05
        filtered.append(np.median(np.linalg.norm(
            np.array([s[1][3:6] for s in steps]) - truth[:, 3:6], axis=1)[judged]))
        smoothed_err.append(np.median(np.linalg.norm(
            np.array([s[0][3:6] for s in states]) - truth[:, 3:6], axis=1)[judged]))
    lo, hi = chi2.ppf([0.005, 0.995], 9 * n) / n
    for phase, values in nees.items():
        assert lo < np.mean(values) < hi, (phase, np.mean(values), lo, hi)
    assert np.median(smoothed_err) <= 0.5 * np.median(filtered), (smoothed_err, filtered)


@pytest.mark.parametrize('velocity', [(-5.0, 0.0, 0.0), (-4.0, 1.5, -2.0), (3.0, -2.0, 1.0)])
def test_the_spin_prior_mean_is_set_on_the_axes_of_the_velocity(velocity):
    """FilterConfig.spin_prior_mean as its docstring defines it: topspin moves the ball's top
    along the horizontal part of v, side spin turns about the vertical (counter-clockwise
    seen from above positive, for a level v) and spin along v is along v."""
    v = np.array(velocity)
    u = v / np.linalg.norm(v)
    h = np.array([v[0], v[1], 0.0]) / np.hypot(v[0], v[1])
    z = np.array([0.0, 0.0, 1.0])

    def start(mean):
        f = BallFilter(config=FilterConfig(spin_prior_mean=mean))
        f.start(0.0, np.zeros(3), v, np.eye(3), np.eye(3))
        return f.x[6:]

    top = start((30.0, 0.0, 0.0))
    assert np.linalg.norm(top) == pytest.approx(30.0)
    assert abs(top @ v) < 1e-9                                 # across v
    assert np.cross(top, z) @ h / 30.0 == pytest.approx(1.0)   # the top moves along v
    along = start((0.0, 0.0, -15.0))
    assert np.allclose(along, -15.0 * u)
    side = start((0.0, 20.0, 0.0))
    assert np.linalg.norm(side) == pytest.approx(20.0)
    assert abs(side @ v) < 1e-9 and abs(side @ top) < 1e-9
    if v[2] == 0.0:
        assert np.allclose(side, 20.0 * z)
    assert side @ z > 0.0
    assert np.allclose(start((30.0, 20.0, -15.0)), top + side + along)
    # Without a mean (the default) the spin starts at zero.
    assert np.allclose(start((0.0, 0.0, 0.0)), 0.0)


def test_dividing_the_prior_out_gives_back_what_the_data_said():
    """spin_likelihood_per_axis inverts Bayes' rule: a prior N(m0, C0) times the data's
    Gaussian likelihood N(y, L^-1) (on the axes of the velocity frame, here with the side and
    along-v axes measured together, correlated, as a bounce does) gives the posterior
    N(m, C); from (m, C, C0, m0) it returns y and each axis's marginal variance diag(L^-1),
    whatever the prior's mean. An axis the data did not inform gives inf."""
    v = np.array([-4.0, 0.8, -2.5])
    E = velocity_frame(v)
    y = np.array([120.0, -35.0, -18.0])
    L_axes = np.array([[1 / 20.0 ** 2, 0.0, 0.0],
                       [0.0, 1 / 30.0 ** 2, 0.8 / (30.0 * 40.0)],
                       [0.0, 0.8 / (30.0 * 40.0), 1 / 40.0 ** 2]])
    C0 = np.diag([250.0, 180.0, 90.0]) ** 2

    def posterior(L_axes, m0):
        L = E.T @ L_axes @ E                                 # the data's information
        C = np.linalg.inv(np.linalg.inv(C0) + L)
        return C @ (np.linalg.solve(C0, m0) + L @ (E.T @ y)), C

    for m0 in (np.zeros(3), np.array([40.0, -60.0, 25.0])):
        m, C = posterior(L_axes, m0)
        got_y, got_s2 = spin_likelihood_per_axis(m, C, C0, v, m0)
        assert np.allclose(got_y, y, atol=1e-6)
        assert np.allclose(got_s2, np.diag(np.linalg.inv(L_axes)), rtol=1e-6)
        # The marginal, not the conditional 1 / L_kk: the correlation widens both.
        assert got_s2[2] > 1.5 / L_axes[2, 2]
    # The mean left out of the division is read as data: the answer moves.
    got_y, _ = spin_likelihood_per_axis(m, C, C0, v)
    assert not np.allclose(got_y, y, atol=1.0)
    # Only top/back spin measured (flight's curvature): the other two axes say nothing.
    only_top = np.diag([1 / 20.0 ** 2, 0.0, 0.0])
    m, C = posterior(only_top, np.zeros(3))
    got_y, got_s2 = spin_likelihood_per_axis(m, C, C0, v)
    assert got_y[0] == pytest.approx(y[0], abs=1e-3)
    assert got_s2[0] == pytest.approx(20.0 ** 2, rel=1e-6)
    assert np.all(np.isinf(got_s2[1:]))


def test_the_spin_outlier_odds_are_the_mixture_priors_posterior_odds():
    """spin_outlier_log_odds against the mixture written out with scipy's normal densities:
    per axis y_k ~ N(mu_k, L_k^2 + s2_k) under the spin prior, N(0, W^2 + s2_k) under the
    outlier component; an axis with s2 inf says nothing; the prior odds (1 - rate) / rate."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        y = rng.normal(0.0, 200.0, 3)
        s2 = rng.uniform(5.0, 150.0, 3) ** 2
        s2[rng.integers(3)] = np.inf
        L, mu = rng.uniform(5.0, 80.0, 3), rng.normal(0.0, 30.0, 3)
        W, rate = rng.uniform(100.0, 400.0), rng.uniform(0.01, 0.5)
        want = np.log((1.0 - rate) / rate) + sum(
            norm.logpdf(y[k], mu[k], np.sqrt(L[k] ** 2 + s2[k]))
            - norm.logpdf(y[k], 0.0, np.sqrt(W ** 2 + s2[k]))
            for k in range(3) if np.isfinite(s2[k]))
        assert spin_outlier_log_odds(y, s2, L, mu, W, rate) == pytest.approx(want, abs=1e-9)


def _backspin_ball(top, rng, noise=5e-4):
    """Samples (times, truth, measured positions) and bounce time of INCOMING's flight with
    ``top`` rad/s of top (> 0) or back spin and nothing else."""
    s0 = INCOMING.copy()
    s0[6:] = velocity_frame(s0[3:6]).T @ np.array([top, 0.0, 0.0])
    times = np.arange(0.0, 0.75, 1.0 / 180.0)
    truth, z = _measured(s0, times, noise, rng)
    events, _ = rollout(s0, ModelParams(), stop_at_plane=False, max_bounces=1)
    return times, truth, z, events[-1].t


def test_a_ball_spun_far_beyond_a_tight_spin_prior_is_followed_by_the_second_filter():
    """A spin prior learned from slow balls (5 rad/s about 0) pins a -250 rad/s backspin
    ball's spin at 0: the filter alone cannot express it. With spin_outlier_rate the second
    filter (spin_outlier_prior 250 rad/s) runs alongside, and the data's curvature makes it
    the more probable: its state is taken within the flight, 100 ms before the bounce, and
    the backspin it carries into the bounce is the ball's, within 3 standard deviations. That
    state is exactly that of a filter run with the wide prior alone."""
    times, truth, z, tb = _backspin_ball(-250.0, np.random.default_rng(4))
    E = velocity_frame(INCOMING[3:6])
    spins, states = {}, {}
    for rate, prior in ((0.05, 5.0), (0.0, 5.0), (0.0, 250.0)):
        cfg = FilterConfig(position_noise=5e-4, spin_prior=prior, spin_outlier_rate=rate)
        tf = TrackFilter(config=cfg)
        took = None
        for t, p in zip(times, z, strict=True):
            tf.add(t, p)
            if took is None and tf.filter is not None and tf.filter.took_outlier:
                took = t
            if t >= tb - 0.02:
                break
        f = tf.filter
        spins[rate, prior] = (E[0] @ f.x[6:], np.sqrt(E[0] @ f.P[6:, 6:] @ E[0]), took)
        states[rate, prior] = (f.x, f.P, f.took_outlier)
    top, sd, took = spins[0.05, 5.0]
    assert took is not None and took < tb - 0.1, (took, tb)
    assert abs(top + 250.0) < 3.0 * sd and sd < 100.0, spins
    top, sd, took = spins[0.0, 5.0]
    assert took is None and abs(top) < 3.0 * 5.0          # pinned by its prior
    x, P, took = states[0.05, 5.0]
    assert took and np.array_equal(x, states[0.0, 250.0][0])
    assert np.array_equal(P, states[0.0, 250.0][1])


def test_balls_of_the_spin_priors_own_population_keep_their_filter():
    """Balls whose spin is drawn from the spin prior itself: the second filter's state is
    taken for few of them (the mixture's posterior odds favour the prior they came from),
    and where it is not, the filter's state is exactly that of a filter without it."""
    rng = np.random.default_rng(6)
    prior, mean = (30.0, 10.0, 10.0), (20.0, 0.0, 0.0)
    times = np.arange(0.0, 0.4, 1.0 / 180.0)
    taken = 0
    for _ in range(20):
        s0 = INCOMING.copy()
        s0[6:] = velocity_frame(s0[3:6]).T @ rng.normal(mean, prior)
        _, z = _measured(s0, times, 5e-4, rng)
        states = []
        for rate in (0.05, 0.0):
            cfg = FilterConfig(position_noise=5e-4, spin_prior=prior[0],
                               spin_prior_side=prior[1], spin_prior_along=prior[2],
                               spin_prior_mean=mean, spin_outlier_rate=rate)
            tf = TrackFilter(config=cfg)
            for t, p in zip(times, z, strict=True):
                tf.add(t, p)
            states.append(tf.filter)
        taken += states[0].took_outlier
        if not states[0].took_outlier:
            assert np.array_equal(states[0].x, states[1].x)
            assert np.array_equal(states[0].P, states[1].P)
    assert taken <= 2, taken


def test_a_trial_copy_of_the_filter_leaves_the_second_filter_alone():
    """perception's pipeline tries an update on a shallow copy of the filter: that update
    must not move the original's second filter (update() replaces it, never changes it)."""
    rng = np.random.default_rng(9)
    times, _, z, _ = _backspin_ball(-250.0, rng)
    cfg = FilterConfig(position_noise=5e-4, spin_prior=5.0)
    f = BallFilter(config=cfg)
    f.start(times[1], z[1], (z[1] - z[0]) / (times[1] - times[0]), np.eye(3) * 2.5e-7,
            np.eye(3) * 0.09)
    assert f.outlier is not None and f.outlier.config.spin_prior == cfg.spin_outlier_prior
    f.predict(times[2])
    before = f.outlier.x.copy()
    trial = copy.copy(f)
    assert trial.update(z[2], np.eye(3) * 2.5e-7)
    assert np.array_equal(f.outlier.x, before)
    assert not np.array_equal(trial.outlier.x, before)
    # A spin prior no tighter than the outlier's, or a rate of 0, runs no second filter.
    for loose in (FilterConfig(spin_prior=300.0, spin_prior_side=250.0),
                  FilterConfig(spin_prior=5.0, spin_outlier_rate=0.0)):
        g = BallFilter(config=loose)
        g.start(0.0, z[1], np.array([-5.0, 0.0, 1.0]), np.eye(3), np.eye(3))
        assert g.outlier is None


@pytest.mark.parametrize('rate', [1.0, -0.1])
def test_a_spin_outlier_rate_outside_0_to_1_is_refused(rate):
    with pytest.raises(ValueError, match='spin_outlier_rate must be'):
        FilterConfig(spin_outlier_rate=rate)


def test_smoothed_covariances_stay_positive_semi_definite_under_a_wide_spin_prior():
    """Under perception's spin prior (250 rad/s standard deviation) the smoother's
    covariances, C0 + G (C_next - C_pred) G^T as a difference, had negative eigenvalues in a
    track's first 0.2 s (tt-perceive --smooth: down to -108, and prediction_node then ignored
    those states' covariance). A covariance has none: each smoothed one, in the coordinates
    of its own standard deviations, must have no eigenvalue below -1e-9."""
    rng = np.random.default_rng(4)
    prior, noise = 250.0, 5e-4
    cfg = FilterConfig(position_noise=noise, spin_prior=prior, accel_noise_speed=0.0)
    times = np.arange(0.0, 0.45, 1.0 / 150.0)
    R = np.eye(3) * noise ** 2
    start_cov = np.diag([noise ** 2] * 3 + [2 * noise ** 2 * 150.0 ** 2 + 0.02 ** 2] * 3
                        + [prior ** 2] * 3)
    worst = 0.0
    for spin in ([0.0, 380.0, -120.0], [40.0, -250.0, 60.0], [0.0, 0.0, 0.0]):
        s0 = INCOMING.copy()
        s0[6:] = spin
        truth, _ = _with_rebound_noise(s0, times, cfg, rng)
        z = truth[:, :3] + rng.normal(0.0, noise, (len(times), 3))
        steps = _run_filter(ModelParams(), cfg, times, z, R, start_cov, spin=np.zeros(3))
        for _, C in smooth(steps, ModelParams(), cfg):
            sd = np.sqrt(np.abs(np.diag(C)))
            worst = min(worst, float(np.linalg.eigvalsh(C / np.outer(sd, sd)).min()))
    assert worst >= -1e-9, worst
