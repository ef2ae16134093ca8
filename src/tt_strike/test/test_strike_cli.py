"""tt-strike: the JSON Lines contract of DESIGN.md, and bad input as one-line errors."""

import io
import json

import numpy as np
import pytest
from scipy.special import ndtr
from tt_prediction.ball import ModelParams, racket_rebound, zone_bounds, zone_centre
from tt_prediction.predict import predict_landing
from tt_strike.cli import main
from tt_strike.workspace import load_workspace

WORKSPACE = load_workspace()

BALL = {'t': 0.5, 'p': [1.3, 0.1, 0.3], 'v': [-6.0, 0.0, 1.0], 'w': [0.0, 0.0, 0.0]}


def run(lines, monkeypatch, capsys, args=()):
    text = '\n'.join(line if isinstance(line, str) else json.dumps(line) for line in lines)
    monkeypatch.setattr('sys.stdin', io.StringIO(text + '\n'))
    code = main(list(args))
    cap = capsys.readouterr()
    return code, [json.loads(x) for x in cap.out.splitlines()], cap.err


def test_zone_and_point_targets(monkeypatch, capsys):
    code, out, err = run([dict(BALL, target_zone=7), dict(BALL, target_point=[0.5, -0.3])],
                         monkeypatch, capsys)
    assert code == 0 and err == '' and len(out) == 2
    params = ModelParams()
    for line, target in zip(out, (zone_centre(7, 1), np.array([0.5, -0.3])), strict=True):
        assert line['status'] == 'ok' and line['reason'] == ''
        # chosen along the path, inside the template workspace, 0.15 s or more ahead
        assert WORKSPACE.contains(line['racket']['position'])
        assert line['hit']['t'] >= BALL['t'] + WORKSPACE.min_time_before_hit
        racket = line['racket']
        assert np.linalg.norm(racket['normal']) == pytest.approx(1.0)
        assert np.linalg.norm(racket['orientation_xyzw']) == pytest.approx(1.0)
        # the racket sends the hit ball where the line says, and that is the target
        hit = line['hit']
        v, w = racket_rebound(hit['v'], hit['w'], racket['normal'], racket['velocity'], params)
        np.testing.assert_allclose(line['ball_out']['v'], v, atol=1e-9)
        land = predict_landing(np.concatenate([hit['p'], v, w]), params)
        assert land.status == 'ok'
        np.testing.assert_allclose(line['landing']['p'], land.landing.p, atol=1e-6)
        assert np.hypot(*(np.array(line['landing']['p'][:2]) - target)) < 5e-3
    assert out[0]['landing']['zone'] == 7 and out[0]['target']['zone'] == 7
    assert out[1]['target']['zone'] == 0


@pytest.mark.parametrize('sigma_y', [0.0, 0.1, 0.3])
def test_covariance_gives_the_probability_of_the_zone(monkeypatch, capsys, sigma_y):
    # Only the hit point's y uncertain (sigma_y, m): flight, racket rebound, table and net are
    # the same at any y, so each landing of the ensemble is the nominal one moved by the
    # ball's own offset, and the share in zone 5 is the normal distribution's mass between
    # the zone's side lines: Phi((y1 - y_L) / sigma) - Phi((y0 - y_L) / sigma); all of it
    # without uncertainty (the nominal landing is inside the zone).
    cov = np.zeros((9, 9))
    cov[1, 1] = sigma_y ** 2
    code, out, _ = run([dict(BALL, target_zone=5, covariance=cov.ravel().tolist())],
                       monkeypatch, capsys)
    assert code == 0 and out[0]['status'] == 'ok' and out[0]['margin'] > 0.0
    _, _, y0, y1 = zone_bounds(5, 1)
    y_land = out[0]['landing']['p'][1]
    if sigma_y == 0.0:
        assert out[0]['in_zone_probability'] == 1.0
    else:
        expected = ndtr((y1 - y_land) / sigma_y) - ndtr((y0 - y_land) / sigma_y)
        assert 0.05 < expected < 0.99
        # 1024 quasi-random (Sobol) samples: the share is within about 1/1024 of the mass.
        assert out[0]['in_zone_probability'] == pytest.approx(expected, abs=0.01)


def test_no_hit_point_and_infeasible_are_statuses(monkeypatch, capsys):
    net = {'t': 0.0, 'p': [0.3, 0.0, 0.1], 'v': [-5.0, 0.0, 0.0], 'w': [0.0, 0.0, 0.0]}
    code, out, err = run([dict(net, target_zone=5), dict(BALL, target_zone=9)], monkeypatch,
                         capsys, ['--max-racket-speed', '0.2'])
    assert code == 0 and err == ''
    assert out[0]['status'] == 'no_hit_point' and out[0]['reason'].startswith('net')
    assert out[0]['racket'] is None
    assert out[1]['status'] == 'infeasible' and 'racket speed' in out[1]['reason']


@pytest.mark.parametrize('line,what', [
    (dict(BALL, target_zone=0), 'target_zone'),
    (dict(BALL, target_zone=10), 'target_zone'),
    (dict(BALL, target_point=[-0.5, 0.0]), 'target_point'),
    (dict(BALL), 'no target'),
    ('{"t": 0, "p": [NaN, 0, 0.3], "v": [-5, 0, 1], "w": [0, 0, 0], "target_zone": 3}', ''),
    ('not json', 'JSON'),
    ('{"t": 0, "p": [1.6, 0.1, 0.3], "v": [-6, 0, 1.5], "w": [0, 1' + '0' * 330
     + ', 0], "target_zone": 3}', '"w" holds an integer too large'),
    (dict(BALL, target_zone=3, covariance=[1.0] * 80), 'covariance'),
    # All -1: eigenvalue -9 along (1, ..., 1), no variance can be negative.
    (dict(BALL, target_zone=3, covariance=[-1.0] * 81),
     '"covariance" is not positive semi-definite (eigenvalue -9)'),
    # Not symmetric: it used to be symmetrised without a word.
    (dict(BALL, target_zone=3, covariance=(np.eye(9) * 1e-6 + np.eye(9, k=1) * 5.0).ravel()
          .tolist()), '"covariance" is not symmetric ('),
    # A point is [x, y] (strike_node's target_point too): it used to take [x, y, z].
    (dict(BALL, target_point=[0.7, 0, 1]), '"target_point" must be 2 numbers [x, y], got'),
    (dict(BALL, target_point=[[0.7, 0.0]]), '"target_point" must be 2 numbers'),
    (dict(BALL, target_point=[0.7, True]), '"target_point" must be 2 numbers'),
    # Left out without a word: the stroke went out without its in-zone probability.
    (dict(BALL, target_zone=3, covarience=np.eye(9).ravel().tolist()),
     'unknown field "covarience" (did you mean "covariance"?)'),
    (dict(BALL, target_zone=3, label='serve'), 'unknown field "label" (the fields: t, p, v'),
])
def test_bad_input_is_a_one_line_error(line, what, monkeypatch, capsys):
    code, out, err = run([dict(BALL, target_zone=1), line], monkeypatch, capsys)
    assert code == 2 and out == []                 # nothing half-written
    assert err.startswith('tt-strike: line 2:') and err.count('\n') == 1 and what in err


def test_aim_inside_zone_refuses_a_line_without_covariance(monkeypatch, capsys):
    # It was answered without a word: in_zone_probability null, aimed at the zone's centre
    # (strike_node refuses the same setting without the probability; a walk-through).
    cov = (np.eye(9) * 1e-4).ravel().tolist()
    code, out, err = run([dict(BALL, target_zone=3, covariance=cov), dict(BALL, target_zone=3)],
                         monkeypatch, capsys, args=['--aim-inside-zone'])
    assert code == 2 and out == [] and err.count('\n') == 1
    assert err.startswith('tt-strike: line 2: --aim-inside-zone needs "covariance"')
    code, out, err = run([dict(BALL, target_zone=3, covariance=cov)], monkeypatch, capsys,
                         args=['--aim-inside-zone'])
    assert code == 0 and len(out) == 1 and 0.0 < out[0]['in_zone_probability'] <= 1.0


def test_a_covariance_symmetric_within_rounding_is_taken(monkeypatch, capsys):
    cov = np.eye(9) * 1e-6
    cov[0, 1], cov[1, 0] = 1e-7, 1e-7 * (1 + 1e-12)
    code, out, err = run([dict(BALL, target_zone=5, covariance=cov.ravel().tolist())],
                         monkeypatch, capsys)
    assert code == 0 and err == '' and out[0]['status'] == 'ok'


@pytest.mark.parametrize('option, value, words', [
    ('--net-clearance', 'nan', 'must be a number in [0.02, 1] m, got nan'),
    # Millimetres: 'the ball does not come down within 3 s' (infeasible), exit 0.
    ('--net-clearance', '200', 'must be a number in [0.02, 1] m, got 200'),
    ('--max-racket-speed', '8000', 'must be a number in [0.1, 30] m/s, got 8000'),
    ('--max-racket-speed', '0', 'must be a number in [0.1, 30] m/s, got 0'),
])
def test_an_option_outside_the_node_range_is_a_one_line_error(option, value, words,
                                                              monkeypatch, capsys):
    # strike_node's parameters of the same names have these ranges (tt-strike took any
    # positive number).
    code, out, err = run([dict(BALL, target_zone=1)], monkeypatch, capsys, [option, value])
    assert code == 2 and out == [] and err == f'tt-strike: {option} {words}\n'


@pytest.mark.parametrize('plane', ['5', '0.01', '-3.5', 'nan'])
def test_a_hit_plane_outside_the_node_range_is_a_one_line_error(plane, monkeypatch, capsys):
    # The prediction node's hit_plane_x range is [-3, 0] m; tt-strike takes the same.
    code, out, err = run([dict(BALL, target_zone=5)], monkeypatch, capsys,
                         ['--hit-plane-x', plane])
    assert code == 2 and out == [] and err.count('\n') == 1
    assert err.startswith('tt-strike: --hit-plane-x ')


def test_hit_plane_x_is_the_old_behaviour(monkeypatch, capsys):
    code, out, _ = run([dict(BALL, target_zone=5)], monkeypatch, capsys,
                       ['--hit-plane-x', '-1.5'])
    assert code == 0 and out[0]['status'] == 'ok'
    assert out[0]['hit']['p'][0] == pytest.approx(-1.5, abs=1e-9)


def test_the_workspace_holds_with_a_hitting_plane_and_a_faster_limit(monkeypatch, capsys,
                                                                     tmp_path):
    """An arm rated 1 m/s got strokes of 2.6 m/s when --max-racket-speed 5 was given (it
    replaced the workspace's limit; strike_node takes the lower), and --hit-plane-x left the
    workspace unread, a missing file included (a walk-through, 6 Dec 2026)."""
    slow = tmp_path / 'slow.yaml'
    slow.write_text('workspace: {shape: box, box: {x: [-2.1, -1.0], y: [-1, 1], z: [0.0, 1.0]},'
                    ' max_racket_speed: 1.0, min_time_before_hit: 0.15}\n')
    for extra in ([], ['--max-racket-speed', '5'], ['--hit-plane-x', '-1.5']):
        code, out, _ = run([dict(BALL, target_zone=8)], monkeypatch, capsys,
                           ['--workspace', str(slow), *extra])
        assert code == 0 and out[0]['status'] == 'infeasible', (extra, out)
        assert 'above limit 1.0 m/s' in out[0]['reason']
    code, out, err = run([dict(BALL, target_zone=8)], monkeypatch, capsys,
                         ['--workspace', str(tmp_path / 'absent.yaml'), '--hit-plane-x', '-1.5'])
    assert code == 2 and out == [] and 'absent.yaml' in err and err.count('\n') == 1
    late = tmp_path / 'late.yaml'
    late.write_text(slow.read_text().replace('max_racket_speed: 1.0', 'max_racket_speed: 8.0')
                    .replace('min_time_before_hit: 0.15', 'min_time_before_hit: 0.9'))
    code, out, _ = run([dict(BALL, target_zone=8)], monkeypatch, capsys,
                       ['--workspace', str(late), '--hit-plane-x', '-1.5'])
    assert code == 0 and out[0]['status'] == 'too_late' and out[0]['racket'] is None
    assert 'below min_time_before_hit 0.900 s' in out[0]['reason']


def test_unreachable_is_a_status(monkeypatch, capsys, tmp_path):
    ws = tmp_path / 'high.yaml'
    ws.write_text('workspace: {shape: box, box: {x: [-2.1, -1.45], y: [-1, 1], z: [1.2, 1.6]},'
                  ' max_racket_speed: 8.0, min_time_before_hit: 0.15}\n')
    code, out, _ = run([dict(BALL, target_zone=5)], monkeypatch, capsys, ['--workspace', str(ws)])
    assert code == 0 and out[0]['status'] == 'unreachable' and out[0]['racket'] is None
    # Every line has every key, null where there is none (a script reading 'margin' failed
    # on a line without a stroke; a walk-through, 6 Dec 2026).
    _, struck, _ = run([dict(BALL, target_zone=5)], monkeypatch, capsys)
    assert struck[0]['status'] == 'ok' and set(out[0]) == set(struck[0])
    assert out[0]['margin'] is None and out[0]['in_zone_probability'] is None


def test_bad_workspace_is_a_one_line_error_naming_the_key(monkeypatch, capsys, tmp_path):
    ws = tmp_path / 'bad.yaml'
    ws.write_text('workspace: {shape: box, box: {x: [-2.1, -1.45], y: [-1, 1], z: [0.5, 0.1]},'
                  ' max_racket_speed: .nan, min_time_before_hit: 0.15}\n')
    code, out, err = run([dict(BALL, target_zone=5)], monkeypatch, capsys,
                         ['--workspace', str(ws)])
    assert code == 2 and out == [] and err.count('\n') == 1
    assert 'workspace.max_racket_speed' in err and err.startswith('tt-strike: ')
