"""Strike solver: eq. 7 inverted, the coupled Newton solve checked forward, infeasible cases.

The forward checks fly the solution with tt_prediction's model directly (racket_rebound, then
rollout to the net plane and on to the first contact), independent of the solver's own
shooting function.
"""

import math

import numpy as np
import pytest
from tt_prediction.ball import (
    NET_HEIGHT,
    ModelParams,
    racket_rebound,
    rollout,
    zone_bounds,
    zone_centre,
    zone_of,
)
from tt_strike.incoming import hit_point
from tt_strike.solver import (
    StrikeSettings,
    ballistic_guess,
    racket_for_outgoing,
    racket_orientation,
    solve,
)

PARAMS = ModelParams()
# Incoming balls (from the opponent's end): flat drive, topspin, backspin, sidespin, lob.
INCOMING = [
    [1.3, 0.10, 0.30, -6.0, 0.0, 1.0, 0.0, 0.0, 0.0],
    [1.2, -0.3, 0.35, -7.0, 0.8, 0.5, -20.0, -150.0, 40.0],
    [1.4, 0.30, 0.30, -6.0, -0.5, 1.8, 0.0, 120.0, 0.0],
    [1.5, 0.00, 0.40, -9.0, 0.3, 0.8, 0.0, -200.0, 0.0],
    [1.3, 0.20, 0.30, -7.0, -0.4, 1.3, 30.0, 0.0, 150.0],
    [1.5, -0.2, 0.40, -5.0, 0.2, 2.8, 0.0, 50.0, 0.0],
]


def hit_states():
    states = []
    for s in INCOMING:
        pred = hit_point(np.array(s), PARAMS)
        assert pred.status == 'ok', (s, pred.reason)
        states.append(pred.hit.state)
    return states


HITS = hit_states()


def fly(hit, normal, racket_velocity, params=PARAMS):
    """Independent forward model: eq. 7 then the flight, net plane then first contact."""
    s = hit.copy()
    s[3:6], s[6:9] = racket_rebound(hit[3:6], hit[6:9], normal, racket_velocity, params)
    events, _ = rollout(s, params, plane_x=0.0, stop_at_net=True, max_bounces=1)
    assert events[-1].kind == 'plane', events
    net = events[-1]
    events, _ = rollout(net.state, params, t0=net.t, stop_at_net=False, max_bounces=1)
    assert events[-1].kind == 'bounce', events
    return events[-1].state, net.state[2] - params.radius - NET_HEIGHT


def test_eq7_inverse_reproduces_the_outgoing_velocity():
    rng = np.random.default_rng(7)
    for _ in range(200):
        v_in = rng.normal([-5, 0, 0], [2, 1, 1.5])
        w_in = rng.normal(0, 150, 3)
        v_out = rng.normal([6, 0, 2], [2, 1, 1])
        normal, rv = racket_for_outgoing(v_in, w_in, v_out, PARAMS)
        assert np.linalg.norm(normal) == pytest.approx(1.0, abs=1e-12)
        assert np.linalg.norm(np.cross(normal, rv)) < 1e-9       # racket moves along normal
        v, _ = racket_rebound(v_in, w_in, normal, rv, PARAMS)
        np.testing.assert_allclose(v, v_out, atol=1e-9)


def test_eq7_inverse_when_the_rubber_alone_turns_the_ball():
    """v_out - (1 - K_v) v_in across the spin and shorter than K_v r |w| (a ball on the centre
    line spinning about y only, sent back along it): alpha = a.n is 0, which divided by
    zero and crashed tt-strike and strike_node. Both mirror normals give v_out (eq. 7
    forward, tt_prediction's racket_rebound); near it the solution is continuous."""
    k_v = PARAMS.k_p / PARAMS.mass
    c = k_v * PARAMS.radius
    v_in = np.array([-4.0, 0.0, -1.0])
    w_in = np.array([0.0, 500.0, 0.0])
    # a = c (w x n) for a normal leaning 0.3 along y: |a| < c |w|, a across w.
    lean = np.array([0.9, 0.3, 0.0]) + np.array([0.0, 0.0, 1.0]) * math.sqrt(1 - 0.9 ** 2
                                                                              - 0.3 ** 2)
    a = c * np.cross(w_in, lean)
    assert a @ w_in == 0.0 and np.linalg.norm(a) < c * np.linalg.norm(w_in)
    v_out = a + (1.0 - k_v) * v_in
    normal, rv = racket_for_outgoing(v_in, w_in, v_out, PARAMS)
    assert np.all(np.isfinite(normal)) and np.linalg.norm(normal) == pytest.approx(1.0)
    assert abs(normal[1]) == pytest.approx(0.3, abs=1e-9)
    v, _ = racket_rebound(v_in, w_in, normal, rv, PARAMS)
    np.testing.assert_allclose(v, v_out, atol=1e-9)
    for tilt in (1e-9, -1e-9):                       # a hair along w: one of the two
        near, _ = racket_for_outgoing(v_in, w_in, v_out + [0.0, tilt, 0.0], PARAMS)
        assert min(np.linalg.norm(near - normal), np.linalg.norm(near - normal * [1, -1, 1])) \
            < 1e-5


def test_a_ball_on_the_centre_line_with_heavy_spin_gets_a_status_not_a_crash():
    # A new user's scan: 22 of 156 such balls raised ZeroDivisionError (exit 1).
    for w_y in (-500.0, 450.0, 500.0, 600.0):
        for zone in (2, 5, 8):
            s = np.array([1.2, 0.0, 0.3, -5.0, 0.0, 1.2, 0.0, w_y, 0.0])
            pred = hit_point(s, PARAMS)
            if pred.status != 'ok':
                continue
            sol = solve(pred.hit.state, PARAMS, target_zone=zone)
            assert sol.status in ('ok', 'infeasible'), sol.reason
            if sol.feasible:
                landing, clearance = fly(pred.hit.state, sol.normal, sol.racket_velocity)
                assert zone_of(landing[0], landing[1]) == (zone, 1) and clearance > 0.0


def test_eq7_inverse_without_spin_is_the_velocity_difference_direction():
    # Without spin, eq. 7's tangential rows leave P_n [v_out - (1 - K_v) v_in] = 0.
    k_v = PARAMS.k_p / PARAMS.mass
    v_in, v_out = np.array([-5.0, 0.5, -1.0]), np.array([6.0, -0.3, 2.5])
    normal, rv = racket_for_outgoing(v_in, np.zeros(3), v_out, PARAMS)
    a = v_out - (1.0 - k_v) * v_in
    np.testing.assert_allclose(normal, a / np.linalg.norm(a), atol=1e-12)
    # normal row: v_out.n = (1 + e_r) s - e_r v_in.n
    s = (normal @ v_out + PARAMS.e_r * normal @ v_in) / (1.0 + PARAMS.e_r)
    np.testing.assert_allclose(rv, s * normal, atol=1e-12)


def test_ballistic_guess_is_exact_without_air():
    vacuum = ModelParams(c_d=0.0, c_m=0.0)
    p = np.array([-1.5, 0.2, 0.25])
    target = (0.9, -0.4, vacuum.radius)
    v = ballistic_guess(p, target, 0.45, vacuum.gravity)
    s = np.concatenate([p, v, np.zeros(3)])
    events, _ = rollout(s, vacuum, plane_x=0.0, max_bounces=1)
    assert events[-1].kind == 'plane' and events[-1].state[2] == pytest.approx(0.45, abs=1e-9)
    events, _ = rollout(events[-1].state, vacuum, t0=events[-1].t, max_bounces=1)
    np.testing.assert_allclose(events[-1].state[:2], target[:2], atol=1e-9)


@pytest.mark.parametrize('zone', range(1, 10))
def test_forward_check_lands_within_5_mm_in_every_zone(zone):
    centre = zone_centre(zone, 1)
    for hit in HITS:
        sol = solve(hit, PARAMS, target_zone=zone)
        assert sol.status == 'ok', sol.reason
        landing, clearance = fly(hit, sol.normal, sol.racket_velocity)
        assert np.hypot(*(landing[:2] - centre)) < 5e-3
        assert zone_of(landing[0], landing[1]) == (zone, 1)
        assert clearance > 0.0
        assert sol.residual < 5e-3
        # the reported outgoing state is eq. 7 of the reported racket
        v, w = racket_rebound(hit[3:6], hit[6:9], sol.normal, sol.racket_velocity, PARAMS)
        np.testing.assert_allclose(sol.ball_out_v, v, atol=1e-12)
        np.testing.assert_allclose(sol.ball_out_w, w, atol=1e-12)


def test_target_point_and_net_clearance_choice():
    hit = HITS[1]
    for clearance in (0.05, 0.2, 0.5):
        for point in ([0.3, 0.6], [1.25, -0.65], [0.8, 0.1]):
            sol = solve(hit, PARAMS, target_point=point,
                        settings=StrikeSettings(net_clearance=clearance))
            assert sol.status == 'ok', sol.reason
            landing, gap = fly(hit, sol.normal, sol.racket_velocity)
            assert np.hypot(*(landing[:2] - point)) < 5e-3
            assert gap == pytest.approx(clearance, abs=1e-3)


def test_higher_clearance_is_a_slower_higher_ball():
    sols = [solve(HITS[0], PARAMS, target_zone=8, settings=StrikeSettings(net_clearance=c))
            for c in (0.05, 0.3, 0.6)]
    assert all(s.status == 'ok' for s in sols)
    vx = [s.ball_out_v[0] for s in sols]
    vz = [s.ball_out_v[2] for s in sols]
    assert vx[0] > vx[1] > vx[2] and vz[0] < vz[1] < vz[2]


def test_racket_quaternion_turns_z_onto_the_normal():
    for hit in HITS:
        sol = solve(hit, PARAMS, target_zone=5)
        x, y, z, w = sol.orientation_xyzw
        assert x * x + y * y + z * z + w * w == pytest.approx(1.0)
        # third column of the rotation matrix of the quaternion
        col_z = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
        np.testing.assert_allclose(col_z, sol.normal, atol=1e-12)
        np.testing.assert_allclose(sol.racket_position, hit[:3] - PARAMS.radius * sol.normal)
    q = racket_orientation([0.0, 0.0, 1.0])            # face up: still a unit quaternion
    assert np.linalg.norm(q) == pytest.approx(1.0)


def test_slow_ball_needs_more_racket_speed_than_the_limit():
    hit = HITS[5]                        # a slow lob
    sol = solve(hit, PARAMS, target_zone=9, settings=StrikeSettings(max_racket_speed=0.5))
    assert sol.status == 'infeasible'
    assert sol.reason.startswith('racket speed') and 'above limit 0.5 m/s' in sol.reason
    speed = float(sol.reason.split()[2])
    assert speed > 0.5


def test_unreachable_hit_points_and_targets():
    low = HITS[0].copy()
    low[2] = -0.5
    sol = solve(low, PARAMS, target_zone=5)
    assert sol.status == 'infeasible' and 'outside reach' in sol.reason
    wide = HITS[0].copy()
    wide[1] = 2.0
    sol = solve(wide, PARAMS, target_zone=5)
    assert sol.status == 'infeasible' and 'beyond reach' in sol.reason
    past_net = HITS[0].copy()
    past_net[0] = 0.5                    # the hit point is already over the opponent's half
    sol = solve(past_net, PARAMS, target_point=[0.3, 0.0])
    assert sol.status == 'infeasible' and sol.reason.startswith('cannot reach the target')
    # a return to the zone next to the net needs the face tilted up by more than 5 deg
    tilt = solve(HITS[0], PARAMS, target_zone=1,
                 settings=StrikeSettings(max_normal_tilt_deg=5.0))
    assert tilt.status == 'infeasible' and 'deg from +x' in tilt.reason


def test_forward_end_says_how_the_forward_check_ended():
    # A ball struck just below the surface 5 cm behind the end line: at the default net
    # clearance the stroke meets the table's end face; 0.4 m over the net it rises steeply
    # enough to clear the edge (tt_strike.hitpoint retries such strokes higher).
    hit = np.array([-1.42, 0.0, -0.01, -3.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    anywhere = {'reach_z': (-math.inf, math.inf), 'reach_y': math.inf}
    edge = solve(hit, PARAMS, target_zone=5, settings=StrikeSettings(**anywhere))
    assert (edge.status, edge.forward_end) == ('infeasible', 'table_edge'), edge.reason
    higher = solve(hit, PARAMS, target_zone=5,
                   settings=StrikeSettings(net_clearance=0.4, **anywhere))
    assert (higher.status, higher.forward_end) == ('ok', 'ok'), higher.reason
    low = HITS[0].copy()
    low[2] = -0.5
    assert solve(low, PARAMS, target_zone=5).forward_end == ''     # no forward check


@pytest.mark.parametrize('zone', [0, 10, -1, 2.5, True, '3'])
def test_bad_target_zone(zone):
    sol = solve(HITS[0], PARAMS, target_zone=zone)
    assert sol.status == 'bad_target' and 'target_zone' in sol.reason
    assert not sol.feasible


@pytest.mark.parametrize('point', [[-0.5, 0.0], [1.5, 0.0], [0.5, 0.9], [math.nan, 0.0],
                                   [0.5]])
def test_bad_target_point(point):
    sol = solve(HITS[0], PARAMS, target_point=point)
    assert sol.status == 'bad_target' and 'target_point' in sol.reason


def test_no_target_or_both():
    assert solve(HITS[0], PARAMS).status == 'bad_target'
    both = solve(HITS[0], PARAMS, target_zone=3, target_point=[0.5, 0.0])
    assert both.status == 'bad_target'


@pytest.mark.parametrize('bad', [[math.nan] + [0.0] * 8, [0.0] * 8, [math.inf] * 9])
def test_invalid_hit_state(bad):
    sol = solve(np.array(bad), PARAMS, target_zone=5)
    assert sol.status == 'invalid' and sol.normal is None


def test_margin_is_the_distance_to_the_zone_edge():
    sol = solve(HITS[0], PARAMS, target_zone=4)
    x0, x1, y0, y1 = zone_bounds(4, 1)
    # at the zone centre the nearest edge is half the zone's smaller side away
    assert sol.margin == pytest.approx(min(x1 - x0, y1 - y0) / 2, abs=5e-3)


@pytest.mark.parametrize('hit', [
    [-1.5, 0.2825, 0.6411, -2.1041, 0.6401, -0.2651, -34.9357, -120.575, -35.8475],
    [-1.5, -0.3985, 0.5999, -2.0542, -0.6011, 0.7969, 32.7782, -112.8171, 7.3513],
])
def test_high_slow_ball_to_the_net_row(hit):
    # Measured balls (DeepMind set) taken high and slow: the drag-free start lands right at
    # the net line, where Newton used to stall.
    hit = np.array(hit)
    for zone in (1, 2, 3):
        sol = solve(hit, PARAMS, target_zone=zone)
        assert sol.status == 'ok', sol.reason
        landing, clearance = fly(hit, sol.normal, sol.racket_velocity)
        assert np.hypot(*(landing[:2] - zone_centre(zone, 1))) < 5e-3 and clearance > 0.0
