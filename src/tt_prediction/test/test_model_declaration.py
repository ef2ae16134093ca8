"""The declaration of the ball model's parameters (params.FIELDS, EFFECTS) and the rebound
effects: layouts generated from it, defaults that are the paper's model, plausible ranges
enforced on model.yaml, and the rebound effects derived from eqs. 1-6."""

import math

import numpy as np
import pytest
import yaml

from tt_prediction import ball

NOMINAL = ball.ModelParams()


def test_packed_layout_follows_the_declaration():
    # Give every slot a distinct value through the fields, find it at its generated index.
    kwargs, expected = {}, {}
    for k, f in enumerate(ball.FIELDS):
        if isinstance(f.default, tuple):
            kwargs[f.name] = tuple(100.0 + 10 * k + c for c in range(len(f.default)))
            expected.update(zip(f.slots, kwargs[f.name], strict=True))
        else:
            kwargs[f.name] = expected[f.name] = 100.0 + 10 * k
    P = ball.ModelParams(**kwargs).packed()
    assert len(P) == ball.N_PACKED == len(ball.PACKED_FIELDS)
    for slot, value in expected.items():
        assert P[ball.INDEX[slot]] == value
    assert P[ball.I_KP] == kwargs['k_p'] and P[ball.I_WIND_Y] == kwargs['wind'][1]
    assert ball.ModelParams.from_packed(P) == ball.ModelParams(**kwargs)


def test_defaults_are_the_papers_model():
    # MODEL.md "Constants", and every effect off.
    p = NOMINAL
    assert (p.mass, p.radius, p.gravity, p.air_density, p.area) == (2.7e-3, 0.020, 9.8, 1.184,
                                                                     12.5e-4)
    assert (p.c_d, p.c_m, p.e_t, p.mu, p.e_r, p.k_p) == (0.54, 0.069, 0.93, 0.25, 0.81, 1.9e-3)
    assert p.active_effects() == []
    assert set(ball.EFFECT_FIELDS) == {f.name for f in ball.FIELDS if f.effect}


def test_k_p_is_a_mass():
    # Eq. 7: K_v = k_p / m is dimensionless, so k_p is in kg.
    assert ball.FIELD['k_p'].unit == 'kg'


def test_every_field_has_a_unit_and_a_plausible_range_holding_its_default():
    for f in ball.FIELDS:
        assert f.unit and f.doc
        lo, hi = f.bounds
        for v in (f.default if isinstance(f.default, tuple) else (f.default,)):
            assert lo <= v <= hi, f.name


@pytest.mark.parametrize('field, value, words', [
    ('c_d', -5, 'c_d = -5 is outside the plausible range 0.1..2'),
    ('c_d', 2.5, 'c_d = 2.5'),
    ('radius', 20, 'radius = 20 m is outside the plausible range 0.015..0.025 m'),
    ('mass', 2.7, 'mass = 2.7 kg'),
    ('e_t', 1.3, 'e_t = 1.3'),
    # Inside k_p's range but over 0.8 m: the rubber would add energy (a user's file, x4.2).
    ('k_p', 0.0045, 'k_p = 0.0045 kg is above 0.8 m = 0.00216 kg'),
])
def test_implausible_model_file_is_one_line_naming_file_and_field(tmp_path, field, value,
                                                                  words):
    path = tmp_path / 'model.yaml'
    path.write_text(yaml.safe_dump({'ball': {field: value}}))
    with pytest.raises(ValueError) as err:
        ball.load_model(str(path))
    message = str(err.value)
    assert '\n' not in message
    assert message.startswith(f'{path}:') and words in message


def test_non_numeric_model_value_is_named(tmp_path):
    path = tmp_path / 'model.yaml'
    path.write_text('ball:\n  c_d: fast\n')
    with pytest.raises(ValueError, match=r'model.yaml: .*c_d must be a number'):
        ball.load_model(str(path))


def test_a_model_field_given_twice_is_refused(tmp_path):
    # PyYAML keeps the second value without a word: both tt-predict and prediction_node
    # started with it (a researcher's walk-through).
    path = _complete_model(tmp_path, lambda d: None)
    path.write_text(path.read_text().replace('ball:\n', 'ball:\n  c_d: 0.3\n', 1))
    with pytest.raises(ValueError) as err:
        ball.load_model(str(path))
    assert str(err.value) == (f"{path}: not valid YAML: the key 'c_d' is given twice "
                              f"(line {path.read_text().splitlines().index('  c_d: 0.54') + 1})")


def _complete_model(tmp_path, edit):
    """A model file as tt-identify writes it (every field), changed by ``edit(data)``."""
    data = ball.ModelParams().to_dict()
    edit(data)
    path = tmp_path / 'model.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize('edit, words', [
    # A ball parameter left out was the nominal one without a word (an identified c_d of
    # 0.45 dropped by a hand edit predicted with 0.54).
    (lambda d: d['ball'].pop('c_d'), 'ball parameter(s) missing: c_d '),
    (lambda d: d.clear(), 'ball parameter(s) missing: mass, radius'),
    # YAML's yes/true were 1.0 and a string of digits a wind of (1, 2, 3) m/s.
    (lambda d: d['ball'].update(c_d=True), 'c_d must be a number, got True'),
    (lambda d: d['ball'].update(e_t='0.9'), "e_t must be a number, got '0.9'"),
    (lambda d: d['effects'].update(wind='123'), "wind must be a list of three numbers, got "
                                                "'123'"),
    (lambda d: d['effects'].update(wind=[0.0, True, 0.0]), 'wind must be a list of three'),
    (lambda d: d['ball'].update(wind=d['effects'].pop('wind')),
     "wind belongs under 'effects', not 'ball'"),
    (lambda d: d['effects'].update(c_m=d['ball'].pop('c_m')),
     "c_m belongs under 'ball', not 'effects'"),
    # In its block and again at the top level: whichever came last ran (a walk-through).
    (lambda d: d.update(c_d=0.7), 'c_d is given twice (again at the top level)'),
    (lambda d: d.update(spin_decay=2.0), 'spin_decay is given twice (again at the top level)'),
    # A key of another type beside an unknown one: a traceback (sorting str with int).
    (lambda d: d.update({1: 2, 'foo': 3}), 'unknown parameter(s) 1, foo'),
])
def test_a_model_file_with_a_field_left_out_or_of_the_wrong_kind_is_refused(tmp_path, edit,
                                                                            words):
    path = _complete_model(tmp_path, edit)
    with pytest.raises(ValueError) as err:
        ball.load_model(str(path))
    assert str(err.value).startswith(f'{path}: model file: ') and words in str(err.value)
    assert '\n' not in str(err.value)


def test_an_effect_left_out_is_not_applied(tmp_path):
    # Files of fewer effects (an older tt-identify) load: a missing effect is 0, off.
    path = _complete_model(tmp_path, lambda d: d['effects'].clear())
    assert ball.load_model(str(path)) == ball.ModelParams()
    path = _complete_model(tmp_path, lambda d: d['ball'].update(c_d=0.45))
    assert ball.load_model(str(path)).c_d == 0.45


def _rebound(v, w, params, position=(0.0, 0.0, 0.0)):
    return ball.table_rebound(np.asarray(v, float), np.asarray(w, float), params, position)


def _contact_velocity(v, w, r=0.020):
    """v_T = (v_x - r w_y, v_y + r w_x) (MODEL.md, table rebound)."""
    return np.array([v[0] - r * w[1], v[1] + r * w[0]])


def test_tangential_compliance_reverses_the_contact_velocity_of_a_gripping_ball():
    # Topspin ball: slip ratio s = mu (1 + e_t)|v_z| / |v_T| well above 2/5 -> grip.
    v, w = np.array([-3.0, 0.4, -3.5]), np.array([10.0, -120.0, 5.0])
    vt = _contact_velocity(v, w)
    assert 0.25 * 1.93 * 3.5 / np.linalg.norm(vt) > 0.4 * 1.5
    for e_x in (0.0, 0.3, 0.5):
        v1, w1 = _rebound(v, w, NOMINAL.replace(e_t_tangential=e_x))
        np.testing.assert_allclose(_contact_velocity(v1, w1), -e_x * vt, atol=1e-12)
        # Normal restitution and w_z as in eqs. 1-6.
        assert v1[2] == pytest.approx(-0.93 * v[2]) and w1[2] == w[2]
    # Spin overshoot: the spin change grows by (1 + e_x) (alpha = 2/5 (1 + e_x)).
    _, w0 = _rebound(v, w, NOMINAL)
    _, w5 = _rebound(v, w, NOMINAL.replace(e_t_tangential=0.5))
    np.testing.assert_allclose(w5[:2] - w[:2], 1.5 * (w0[:2] - w[:2]), rtol=1e-12)


def test_tangential_compliance_leaves_a_sliding_ball_alone_and_adds_no_energy():
    # Backspin, fast: s well below 2/5 -> sliding, alpha = s, independent of e_x.
    v, w = np.array([-6.0, 0.0, -2.0]), np.array([0.0, 250.0, 0.0])
    s = 0.25 * 1.93 * 2.0 / np.linalg.norm(_contact_velocity(v, w))
    assert s < 0.4
    a = _rebound(v, w, NOMINAL)
    b = _rebound(v, w, NOMINAL.replace(e_t_tangential=0.6))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    rng = np.random.default_rng(1)
    p = NOMINAL.replace(e_t_tangential=0.9)
    for _ in range(500):
        v = rng.uniform(-8, 8, 3)
        v[2] = -abs(v[2]) - 0.1
        w = rng.uniform(-600, 600, 3)
        v1, w1 = _rebound(v, w, p)
        energy = 0.5 * p.mass * v @ v + 0.5 * p.inertia * w @ w
        assert 0.5 * p.mass * v1 @ v1 + 0.5 * p.inertia * w1 @ w1 <= energy * (1 + 1e-12)


def test_restitution_depends_on_impact_speed_and_spin():
    v, w = np.array([-4.0, 0.0, -3.0]), np.array([0.0, 200.0, 0.0])
    p = NOMINAL.replace(e_t_spin_slope=-0.01, e_t_speed_slope=-0.05)
    v1, _ = _rebound(v, w, p)
    # e_t = 0.93 - 0.05 (|v_z| - 3) - 0.01 r |w| = 0.93 - 0 - 0.04
    assert v1[2] == pytest.approx(3.0 * (0.93 - 0.01 * 0.020 * 200.0), rel=1e-12)


@pytest.mark.parametrize('place, edge', [((-1.32, 0.1), 0.05), ((1.32, -0.1), 0.05),
                                         ((-0.6, 0.7425), 0.02), ((0.0, 0.0), 0.7625)])
def test_restitution_depends_on_how_near_the_ball_lands_to_the_tables_edge(place, edge):
    # e_t = 0.93 + e_t_edge exp(-d / 0.1 m), d the distance to the nearest edge of the
    # 2.74 x 1.525 m outline, on either half and either side.
    v, w = np.array([-4.0, 0.0, -3.0]), np.array([0.0, 0.0, 0.0])
    v1, _ = _rebound(v, w, NOMINAL.replace(e_t_edge=-0.08), position=(*place, 0.02))
    assert v1[2] == pytest.approx(3.0 * (0.93 - 0.08 * math.exp(-edge / 0.1)), rel=1e-12)
    assert ball.edge_distance(*place) == pytest.approx(edge, abs=1e-12)


def test_friction_depends_on_slip_speed():
    # Sliding: alpha = mu (1 + e_t)|v_z| / |v_T| with mu = 0.25 + slope (|v_T| - 4 m/s).
    v, w = np.array([-7.0, 0.0, -2.0]), np.array([0.0, 100.0, 0.0])
    vt = np.linalg.norm(_contact_velocity(v, w))
    slope = 0.02
    mu = 0.25 + slope * (vt - ball.SLIP_SPEED_REF)
    alpha = mu * 1.93 * 2.0 / vt
    assert alpha < 0.4
    v1, w1 = _rebound(v, w, NOMINAL.replace(mu_slip_slope=slope))
    assert v1[0] == pytest.approx((1 - alpha) * v[0] + alpha * 0.020 * w[1], rel=1e-12)
    assert w1[1] == pytest.approx((1 - 1.5 * alpha) * w[1] + 1.5 * alpha / 0.020 * v[0],
                                  rel=1e-12)
    assert math.isclose(mu, 0.25 + 0.02 * (vt - 4.0))


def test_gravity_along_a_table_not_level_adds_to_the_flight_as_it_is():
    # Eq. 8 with g = (g_x, g_y, -g): a ball at rest in still air accelerates by g alone, and
    # a moving one by g_x, g_y more than over a level table, whatever drag and Magnus do.
    p = NOMINAL.replace(gravity_x=0.17, gravity_y=-0.05)
    a = np.empty(9)
    ball.flight_derivative(np.zeros(9), p.packed(), a)
    assert a[3:6] == pytest.approx([0.17, -0.05, -9.8], abs=1e-15)
    assert p.gravity_vector.tolist() == [0.17, -0.05, -9.8]   # the filters' start
    s = np.array([1.0, 0.2, 0.3, -5.0, 0.4, 1.0, 10.0, -150.0, 30.0])
    level = np.empty(9)
    ball.flight_derivative(s, NOMINAL.packed(), level)
    ball.flight_derivative(s, p.packed(), a)
    assert a[3:6] - level[3:6] == pytest.approx([0.17, -0.05, 0.0], abs=1e-12)


def test_the_predictor_runs_the_effects_that_model_yaml_selects(tmp_path):
    # What tt-identify writes is what prediction_node and tt-predict load (load_model) and
    # run. Without air (c_d = c_m = 0) the flight is a parabola, so the bounce and the hit
    # follow by hand from eqs. 1-6 with the gripping alpha = 2/5 (1 + e_x).
    from tt_prediction.predict import predict
    e_x = 0.5
    path = tmp_path / 'model.yaml'
    selected = NOMINAL.replace(e_t_tangential=e_x, mu_slip_slope=0.01)
    selected.save(path, meta={'selected_effects': ['table_compliance']})
    assert ball.load_model(str(path)) == selected
    assert ball.load_model(str(path)).active_effects() == ['e_t_tangential', 'mu_slip_slope']
    # No air is implausible in a file (c_d below 0.1), so the parabola uses the structure.
    params = NOMINAL.replace(c_d=0.0, c_m=0.0, e_t_tangential=e_x)
    p0, v0, w = np.array([1.2, 0.1, 0.35]), np.array([-5.0, 0.4, 0.8]), np.array([0, -200, 0])
    g, r = 9.8, 0.020
    t_b = (v0[2] + math.sqrt(v0[2] ** 2 + 2.0 * g * (p0[2] - r))) / g
    v_in = np.array([v0[0], v0[1], v0[2] - g * t_b])
    slip = 0.25 * 1.93 * abs(v_in[2]) / np.linalg.norm(_contact_velocity(v_in, w))
    alpha = 0.4 * (1.0 + e_x)
    assert slip > alpha                                   # the ball grips
    v1 = np.array([(1 - alpha) * v_in[0] + alpha * r * w[1],
                   (1 - alpha) * v_in[1] - alpha * r * w[0], -0.93 * v_in[2]])
    bounce = p0 + v0 * t_b + [0.0, 0.0, -0.5 * g * t_b ** 2]
    t_h = (-1.5 - bounce[0]) / v1[0]
    pred = predict(np.r_[p0, v0, w], params)
    assert pred.status == 'ok'
    np.testing.assert_allclose(pred.bounce.p[:2], bounce[:2], atol=1e-8)
    np.testing.assert_allclose(pred.hit.p, [-1.5, bounce[1] + v1[1] * t_h,
                                            r + v1[2] * t_h - 0.5 * g * t_h ** 2], atol=1e-8)
    # The paper's model (e_x = 0) puts the hit elsewhere: the effect is not ignored.
    plain = predict(np.r_[p0, v0, w], NOMINAL.replace(c_d=0.0, c_m=0.0))
    assert abs(plain.hit.t - pred.hit.t) > 0.005        # v_x after: -4.6 against -4.4 m/s
