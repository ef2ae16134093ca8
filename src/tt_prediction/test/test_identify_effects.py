"""tt-identify on measured-looking synthetic data with a planted effect (or none).

The data are generated with the model plus one effect that the baseline model does not
declare, 150 Hz, 1.5 mm noise, drop-outs, outliers of 3 to 8 cm, stamp jitter. The tool
must select that effect alone, recover its parameter within the stated tolerance, and at
least halve the held-out hit-plane error; on clean data it must select nothing.
"""

import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from tt_prediction.ball import HALF_LENGTH, HALF_WIDTH
from tt_prediction.identify.cli import main
from tt_prediction.identify.data import Track
from tt_prediction.identify.pipeline import identify
from tt_prediction.identify.synthetic import launch_states, make_tracks
from tt_prediction.params import PACKED_FIELDS, ModelParams
from tt_prediction.reference import table_rebound

N_TRACKS = 14
FOLDS = 3

# effect name, planted model change, fitted parameter, true value, tolerance
PLANTED = [
    ('spin_decay', {'spin_decay': 1.5}, 'spin_decay', 1.5, 0.15),
    ('wind', {'wind': (0.0, 1.0, 0.0)}, 'wind_y', 1.0, 0.1),
    ('table_restitution_speed', {'e_t_speed_slope': -0.15}, 'e_t_speed_slope', -0.15, 0.02),
    ('gravity_or_scale', {'gravity': 10.3}, 'gravity', 10.3, 0.1),
]


@pytest.mark.parametrize('effect, change, param, true, tol', PLANTED,
                         ids=[p[0] for p in PLANTED])
def test_planted_effect_is_found_and_pays(effect, change, param, true, tol):
    tracks = make_tracks(N_TRACKS, ModelParams(**change), seed=1)
    result = identify(tracks, folds=FOLDS)
    assert result['selected_effects'] == [effect]
    assert abs(result['final']['params'][param] - true) <= tol
    # The model that model.yaml receives carries the effect.
    model = result['_model'].packed()
    assert abs(model[PACKED_FIELDS.index(param)] - true) <= tol
    before, after = result['baseline'], result['final']
    assert before['n_hits'] >= N_TRACKS // 2
    assert after['hit_err_mm'] <= 0.5 * before['hit_err_mm']
    tested = {e['name']: e for e in result['effects_tested'] if e.get('round') == 1}
    # The planted effect is the best of the library on held-out data.
    assert max(tested.values(), key=lambda e: e['heldout_gain'])['name'] == effect


def _write_folder(folder, tracks):
    """Trajectory folder of DESIGN.md: one CSV per track and index.csv with the spin."""
    folder.mkdir()
    rows = ['file,wx,wy,wz,label,source_id']
    for i, tr in enumerate(tracks):
        name = f'{i:04d}.csv'
        lines = ['t,x,y,z'] + [f'{t:.6f},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}'
                               for t, p in zip(tr.t, tr.p, strict=True)]
        (folder / name).write_text('\n'.join(lines) + '\n')
        w = tr.spin
        rows.append(f'{name},{w[0]:.3f},{w[1]:.3f},{w[2]:.3f},synthetic,{i}')
    (folder / 'index.csv').write_text('\n'.join(rows) + '\n')


def test_clean_data_selects_nothing_through_the_command(tmp_path):
    data = tmp_path / 'clean'
    _write_folder(data, make_tracks(N_TRACKS, ModelParams(), seed=2))
    out = tmp_path / 'report'
    assert main([str(data), '--out', str(out), '--folds', str(FOLDS), '--no-progress']) == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['selected_effects'] == []
    for e in report['effects_tested']:
        assert not e.get('pays')
    # The contract of DESIGN.md: baseline and final with params and held-out errors.
    for key in ('baseline', 'final'):
        for field in ('params', 'rms_mm', 'bounce_err_mm', 'hit_err_mm', 'zone_accuracy'):
            assert report[key][field] is not None
    assert {'name', 'params', 'heldout_gain'} <= set(report['effects_tested'][0])
    # Clean data: the paper's coefficients come back (nominal C_D 0.54, C_M 0.069).
    assert abs(report['final']['params']['c_d'] - 0.54) < 0.02
    assert abs(report['final']['params']['c_m'] - 0.069) < 0.01
    model = ModelParams.load(out / 'model.yaml')
    assert model.active_effects() == []
    for name in ('report.md', 'residual_vs_time.png', 'landing_errors.png'):
        assert (out / name).stat().st_size > 0


@pytest.mark.slow   # 14 s; the measured-spin cases above cover selection by default
def test_planted_effect_is_found_with_unmeasured_spin():
    # The real sets' case: 9 unknowns per track, the spin estimated jointly. The fit must
    # reach the tracker noise (1.5 mm per axis) once the planted effect is in the model.
    # The hit-plane error is not asserted: predicted from 100 ms with the spin unknown, it
    # is dominated by the spin estimate (about 0.1 m), which no global effect can fix.
    tracks = make_tracks(N_TRACKS, ModelParams(e_t_speed_slope=-0.15), seed=1,
                         spin_known=False)
    result = identify(tracks, folds=FOLDS)
    assert result['selected_effects'] == ['table_restitution_speed']
    assert abs(result['final']['params']['e_t_speed_slope'] + 0.15) <= 0.02
    assert result['final']['heldout_fit_rms_mm'] < 1.6 < result['baseline']['heldout_fit_rms_mm']


def _measured_tracks(launches, seed, gravity=(0.0, 0.0, -9.8), e_t_at=None, rate=150.0,
                     noise=0.0015):
    """Balls flown by scipy's DOP853 from eq. 8 written out here (not tt's kernels) under
    ``gravity`` (m/s^2, table frame), bounced at z = r by the reference's eqs. 1-6 with the
    restitution ``e_t_at(bounce point)`` (the nominal 0.93 if None), sampled at 150 Hz with
    1.5 mm of noise and 5 % drop-outs. Returns the tracks and each one's bounce points."""
    p = ModelParams()
    g = np.asarray(gravity, dtype=float)
    k_drag = 0.5 * p.c_d * p.air_density * p.area / p.mass
    k_lift = 4.0 / 3.0 * p.c_m * math.pi * p.air_density * p.radius ** 3 / p.mass

    def rhs(_t, s):
        v, w = s[3:6], s[6:9]
        return np.concatenate([v, g - k_drag * np.linalg.norm(v) * v
                               + k_lift * np.cross(w, v), np.zeros(3)])

    def table(_t, s):
        over = abs(s[0]) <= HALF_LENGTH and abs(s[1]) <= HALF_WIDTH
        return s[2] - p.radius if over else 1.0
    table.terminal, table.direction = True, -1.0
    rng = np.random.default_rng(seed)
    tracks, bounces = [], []
    for i, s0 in enumerate(launches):
        times = np.arange(0.0, 0.9, 1.0 / rate)
        samples = np.full((len(times), 3), np.nan)
        t, s, points = 0.0, s0, []
        while True:
            sol = solve_ivp(rhs, (t, times[-1]), s, method='DOP853', rtol=1e-10, atol=1e-12,
                            events=table, dense_output=True)
            end = sol.t_events[0][0] if len(sol.t_events[0]) else times[-1]
            now = (times >= t) & (times <= end)
            samples[now] = sol.sol(times[now])[:3].T
            if not len(sol.t_events[0]):
                break
            s = sol.y_events[0][0]
            points.append(s[:2].copy())
            e_t = p.e_t if e_t_at is None else e_t_at(s[:2])
            v, w = table_rebound(s[3:6], s[6:9], p.replace(e_t=e_t))
            t, s = end, np.concatenate([s[:3], v, w])
        keep = (samples[:, 0] > -2.0) & (samples[:, 2] > 0.0)
        keep &= rng.random(len(times)) > 0.05
        tracks.append(Track(f'measured/{i:04d}', times[keep],
                            samples[keep] + rng.normal(0.0, noise, (keep.sum(), 3)),
                            s0[6:9].copy(), 'synthetic'))
        bounces.append(points)
    return tracks, bounces


def _tracks_over_a_table_not_level(n, tilt_deg, seed=1):
    """Balls over a table tilted by ``tilt_deg`` about its x axis, measured in its own frame
    (the bounces at z = r): gravity g (0, sin, -cos) there."""
    tilt = math.radians(tilt_deg)
    gravity = 9.8 * np.array([0.0, math.sin(tilt), -math.cos(tilt)])
    rng = np.random.default_rng(seed)
    return _measured_tracks(launch_states(n, rng), seed, gravity)[0]


def _balls_landing_near_the_edges(n, e_t_at, seed=3):
    """``n`` served balls, every other one bouncing within 12 cm of the robot half's end or
    side line (the serves of launch_states land 35 cm and more inside), restitution
    ``e_t_at(bounce point)``."""
    rng = np.random.default_rng(seed)
    tracks = []
    while len(tracks) < n:
        s0 = launch_states(1, rng)[0]
        s0[3:5] = rng.uniform(-7.5, -4.5), rng.uniform(-1.5, 1.5)
        track, bounces = _measured_tracks([s0], seed + len(tracks), e_t_at=e_t_at)
        if not bounces[0] or bounces[0][0][0] > 0.0:
            continue
        x, y = bounces[0][0]
        near = min(HALF_LENGTH - abs(x), HALF_WIDTH - abs(y)) < 0.12
        if near == (len(tracks) % 2 == 0):
            tracks += track
    return tracks


def test_a_table_not_level_is_found_as_gravity_along_it():
    # 0.5 deg about x: 9.8 sin(0.5 deg) = 0.0855 m/s^2 along +y, constant. A draft across
    # (wind) gives a sideways acceleration too, but one that grows with the ball's speed.
    tracks = _tracks_over_a_table_not_level(N_TRACKS, 0.5)
    result = identify(tracks, folds=FOLDS)
    assert result['selected_effects'] == ['gravity_tilt']
    fitted = result['final']['params']
    assert abs(fitted['gravity_y'] - 9.8 * math.sin(math.radians(0.5))) <= 0.01
    assert abs(fitted['gravity_x']) <= 0.01
    assert result['final']['hit_err_mm'] <= 0.5 * result['baseline']['hit_err_mm']


def test_a_table_deader_near_its_edges_is_found_where_the_balls_land():
    # e_t = 0.93 - 0.12 exp(-d / 0.1 m), d the bounce's distance to the nearest edge: the
    # ball leaves the table 3.2 to 12 % slower upwards within 10 cm of an edge. No flight
    # effect and no other rebound effect (impact speed, spin, friction) gives that.
    def e_t_at(point):
        d = min(HALF_LENGTH - abs(point[0]), HALF_WIDTH - abs(point[1]))
        return 0.93 - 0.12 * math.exp(-d / 0.1)
    tracks = _balls_landing_near_the_edges(N_TRACKS, e_t_at)
    result = identify(tracks, folds=FOLDS)
    assert result['selected_effects'] == ['table_restitution_edge']
    assert abs(result['final']['params']['e_t_edge'] + 0.12) <= 0.02
    before, after = result['baseline'], result['final']
    assert after['post_bounce_rms_mm'] <= 0.5 * before['post_bounce_rms_mm']


def test_a_dead_band_along_the_edges_is_taken_up_by_the_edge_restitution():
    # A shape the library does not have: e_t 0.85 within 10 cm of an edge, 0.93 elsewhere
    # (a step, where the effect fades exponentially). Still the edge effect alone pays, and
    # takes a third or more off the error after the bounce (its shape, not its size, is off).
    def e_t_at(point):
        d = min(HALF_LENGTH - abs(point[0]), HALF_WIDTH - abs(point[1]))
        return 0.85 if d < 0.1 else 0.93
    result = identify(_balls_landing_near_the_edges(N_TRACKS, e_t_at), folds=FOLDS)
    assert result['selected_effects'] == ['table_restitution_edge']
    assert result['final']['params']['e_t_edge'] < -0.05
    before, after = result['baseline'], result['final']
    assert after['post_bounce_rms_mm'] <= 0.75 * before['post_bounce_rms_mm']


def test_balls_landing_near_the_edges_of_an_even_table_select_nothing():
    result = identify(_balls_landing_near_the_edges(N_TRACKS, lambda point: 0.93), folds=FOLDS)
    assert result['selected_effects'] == []
    assert abs(result['final']['params']['e_t'] - 0.93) <= 0.01
