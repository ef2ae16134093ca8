"""The robot's reach: the workspace file, its validation, and the hit point chosen along the
predicted trajectory inside it (tt_strike.workspace, tt_strike.hitpoint)."""

import math

from body_reference import replay_stroke
import numpy as np
import pytest
from tt_prediction.ball import ModelParams
from tt_prediction.predict import predict
from tt_strike.hitpoint import SWITCH_MARGIN, choose
from tt_strike.workspace import TEMPLATE, Workspace, WorkspaceError, load_workspace
import yaml

PARAMS = ModelParams()
BALL = np.array([1.3, 0.1, 0.3, -6.0, 0.0, 1.0, 0.0, 0.0, 0.0])
TEMPLATE_DATA = yaml.safe_load(TEMPLATE.read_text())


def write(tmp_path, data):
    path = tmp_path / 'ws.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def test_template_is_a_box_behind_the_end_line():
    ws = load_workspace()
    assert ws.shape == 'box' and ws.x[1] < -1.37 and ws.z[0] < 0.0 < ws.z[1]
    assert ws.max_racket_speed > 0.0 and ws.min_time_before_hit > 0.0
    assert ws.contains([-1.6, 0.0, 0.2]) and not ws.contains([-1.0, 0.0, 0.2])


def test_cylinder_contains_by_distance_to_its_axis(tmp_path):
    data = {'workspace': {'shape': 'cylinder', 'max_racket_speed': 6.0,
                          'min_time_before_hit': 0.1,
                          'cylinder': {'centre': [-2.0, 0.0], 'radius': 0.5, 'z': [0, 1]}}}
    ws = load_workspace(write(tmp_path, data))
    # 0.3 and 0.4 from the axis: 0.5 away, on the surface; 0.51 away, outside.
    assert ws.contains([-1.7, 0.4, 0.5]) and not ws.contains([-1.694, 0.408, 0.5])
    assert ws.x_range() == (-2.5, -1.5)


@pytest.mark.parametrize('edit, key', [
    (lambda d: d['workspace'].pop('max_racket_speed'), 'workspace.max_racket_speed'),
    (lambda d: d['workspace']['box'].pop('z'), 'workspace.box.z'),
    (lambda d: d['workspace'].update(min_time_before_hit=-0.1), 'workspace.min_time_before_hit'),
    (lambda d: d['workspace'].update(max_racket_speed=float('nan')), 'max_racket_speed'),
    (lambda d: d['workspace']['box'].update(x=[-1.4, -2.0]), 'workspace.box.x'),
    (lambda d: d['workspace']['box'].update(y=[0.5, float('nan')]), 'workspace.box.y'),
    (lambda d: d['workspace'].update(shape='sphere'), 'workspace.shape'),
    (lambda d: d['workspace'].update(shape='cylinder'), 'workspace.cylinder'),
    (lambda d: d.pop('workspace'), 'workspace'),
    # Millimetres and milliseconds gave 'unreachable' and 'too_late' statuses, and a
    # misspelt key was ignored, each without a word.
    (lambda d: d['workspace']['box'].update(x=[-2100, -1450]),
     "'workspace.box.x' must be within [-10, 10] m, got -2100 (metres, not millimetres?)"),
    (lambda d: d['workspace'].update(min_time_before_hit=150),
     "'workspace.min_time_before_hit' must be within [0, 2] s, got 150 (seconds, not "
     'milliseconds?)'),
    (lambda d: d['workspace'].update(max_racket_speed=8000),
     "'workspace.max_racket_speed' must be within [0.1, 30] m/s, got 8000"),
    (lambda d: d['workspace'].update(max_racket_sped=8.0),
     "unknown key 'workspace.max_racket_sped'"),
    (lambda d: d['workspace']['box'].update(w=[0, 1]), "unknown key 'workspace.box.w'"),
    (lambda d: d.update(extra=1), "unknown key 'extra' (known: workspace)"),
    # Its lines commented out, the key left: a traceback (a walk-through, 6 Dec 2026).
    (lambda d: d['workspace'].update(box=None), "key 'workspace.box' must be a mapping of x"),
])
def test_bad_files_name_the_key_in_one_line(tmp_path, edit, key):
    data = yaml.safe_load(TEMPLATE.read_text())
    edit(data)
    with pytest.raises(WorkspaceError) as err:
        load_workspace(write(tmp_path, data))
    text = str(err.value)
    assert key in text and '\n' not in text


@pytest.mark.parametrize('text, reason', [
    ('', ': empty'), ('# only a comment\n', ': empty'),
    ('- workspace\n', ': the top level must be a mapping'),
    ('workspace: 3\n', ": key 'workspace' must be a mapping"),
])
def test_a_file_that_is_no_mapping_says_so(tmp_path, text, reason):
    path = tmp_path / 'ws.yaml'
    path.write_text(text)
    with pytest.raises(WorkspaceError) as err:
        load_workspace(path)
    assert str(err.value) == f'{path}{reason}'


def test_negative_cylinder_radius(tmp_path):
    data = {'workspace': {'shape': 'cylinder', 'max_racket_speed': 6.0,
                          'min_time_before_hit': 0.1,
                          'cylinder': {'centre': [-2.0, 0.0], 'radius': -0.5, 'z': [0, 1]}}}
    with pytest.raises(WorkspaceError, match='workspace.cylinder.radius'):
        load_workspace(write(tmp_path, data))


def test_chosen_hit_is_on_the_path_inside_the_reach_and_lands_in_the_zone():
    ws = load_workspace()
    plan = choose(BALL, PARAMS, ws, t0=0.5, target_zone=8)
    assert plan.status == 'ok', plan.reason
    sol, hit = plan.solution, plan.hit
    assert ws.contains(sol.racket_position) and hit.t >= 0.5 + ws.min_time_before_hit
    assert np.linalg.norm(sol.racket_velocity) <= ws.max_racket_speed
    # The hit state is the predicted ball where it crosses the plane x = hit.p[0].
    at_plane = predict(BALL, PARAMS, t0=0.5, hit_plane_x=hit.p[0])
    np.testing.assert_allclose(at_plane.hit.p, hit.p, atol=1e-6)
    np.testing.assert_allclose(at_plane.hit.v, hit.v, atol=1e-5)
    assert at_plane.hit.t == pytest.approx(hit.t, abs=1e-6)
    # The independent reference flies the racket command into zone 8.
    zone, contact = replay_stroke(hit.state, sol.normal, sol.racket_velocity)
    assert zone == 8, contact
    assert plan.candidates >= 2 and 0.0 < plan.score <= 1.0


def test_unreachable_and_too_late_have_reasons():
    high = Workspace('box', x=(-2.1, -1.45), y=(-0.9, 0.9), z=(1.2, 1.6))
    plan = choose(BALL, PARAMS, high, target_zone=5)
    assert plan.status == 'unreachable' and 'z [1.20, 1.60]' in plan.reason
    slow_arm = Workspace('box', x=(-2.1, -1.45), y=(-0.9, 0.9), z=(-0.25, 0.75),
                         min_time_before_hit=2.0)
    plan = choose(BALL, PARAMS, slow_arm, target_zone=5)
    assert plan.status == 'too_late' and 'min_time_before_hit 2.000' in plan.reason
    # Decided 0.149 s before the ball leaves the reach (grown by r: x = -2.12): too late.
    ws = load_workspace()
    t_exit = predict(BALL, PARAMS, hit_plane_x=ws.x[0] - PARAMS.radius).hit.t
    late = choose(BALL, PARAMS, ws, now=t_exit - ws.min_time_before_hit + 1e-3,
                  target_zone=5)
    assert late.status == 'too_late', late.reason


def test_a_ball_keeps_its_hit_time_from_one_prediction_to_the_next():
    # The same flight predicted at 150 Hz: each decision drops the rows that became too soon,
    # and the hit point chosen among the rest moved on by 10 ms every few frames, 0.22 s in
    # all (an arm following the commands would chase it). Kept, the hit time is chosen once;
    # once it is closer than min_time_before_hit, the arm is on its way: too_late, kept.
    ws = load_workspace()
    keep, chosen, solved = None, [], []
    for k in range(200):
        now = k / 150.0
        plan = choose(BALL, PARAMS, ws, now=now, target_zone=5, keep_t=keep)
        if plan.status != 'ok':
            break
        keep = plan.hit.t
        chosen.append(plan.hit)
        solved.append((plan.candidates, plan.score))
    assert plan.status == 'too_late' and 'kept' in plan.reason, plan.reason
    # A kept hit scoring 1 - SWITCH_MARGIN or more cannot be beaten (scores are at most 1):
    # the other candidates are not solved.
    assert solved[0][0] >= 2
    beyond = [n for n, score in solved[1:] if score >= 1.0 - SWITCH_MARGIN]
    assert beyond and set(beyond) == {1}
    assert keep - now < ws.min_time_before_hit <= keep - (now - 1 / 150.0)
    assert len(chosen) > 50
    assert {h.t for h in chosen} == {chosen[0].t}
    np.testing.assert_allclose([h.p for h in chosen], [chosen[0].p] * len(chosen), atol=1e-9)
    # The kept hit is the flight's own state at that time (interpolated between 10 ms rows).
    at = predict(BALL, PARAMS, hit_plane_x=chosen[0].p[0]).hit
    assert at.t == pytest.approx(chosen[0].t, abs=1e-4)
    np.testing.assert_allclose(at.p, chosen[0].p, atol=2e-5)
    # A kept time the path no longer reaches (the prediction changed) is chosen afresh.
    fresh = choose(BALL, PARAMS, ws, target_zone=5)
    gone = choose(BALL, PARAMS, ws, target_zone=5, keep_t=5.0)
    assert gone.status == 'ok' and gone.hit.t == fresh.hit.t


def test_racket_speed_limit_of_the_workspace():
    weak = Workspace('box', x=(-2.1, -1.45), y=(-0.9, 0.9), z=(-0.25, 0.75),
                     max_racket_speed=0.2)
    plan = choose(BALL, PARAMS, weak, target_zone=9)
    assert plan.status == 'infeasible' and 'racket speed' in plan.reason
    assert math.isnan(plan.score)
