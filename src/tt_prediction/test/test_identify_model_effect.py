"""The spin-dependent drag effect added to the model for tt-identify (params.py, model.py).

C_D = c_d + slope (r|w|/|u| - 0.3), u the air-relative velocity: at a given state the drag
must equal that of the plain model with C_D shifted by slope times the spin-ratio excess,
and the lift must not change.
"""

import numpy as np
from tt_prediction.integrate import rollout
from tt_prediction.model import flight_acceleration
from tt_prediction.params import LIFT_SPIN_RATIO_REF, ModelParams


def test_spin_dependent_drag_is_a_shift_of_c_d_by_the_spin_ratio():
    p = np.zeros(3)
    v = np.array([-5.0, 0.5, 1.0])
    w = np.array([10.0, 200.0, -30.0])
    slope = 0.4
    ratio = 0.02 * np.linalg.norm(w) / np.linalg.norm(v)
    with_effect = flight_acceleration(p, v, w, ModelParams(c_d_spin_ratio_slope=slope))
    shifted = ModelParams(c_d=0.54 + slope * (ratio - LIFT_SPIN_RATIO_REF))
    np.testing.assert_allclose(with_effect, flight_acceleration(p, v, w, shifted), rtol=1e-12)
    # More spin, more drag: the acceleration along -v grows.
    more = flight_acceleration(p, v, 2 * w, ModelParams(c_d_spin_ratio_slope=slope))
    base2 = flight_acceleration(p, v, 2 * w, ModelParams())
    v_hat = v / np.linalg.norm(v)
    assert (base2 - more) @ v_hat > (flight_acceleration(p, v, w, ModelParams())
                                     - with_effect) @ v_hat > 0.0


def test_spin_dependent_drag_round_trips_through_model_yaml(tmp_path):
    params = ModelParams(c_d_spin_ratio_slope=0.25)
    params.save(tmp_path / 'model.yaml')
    loaded = ModelParams.load(tmp_path / 'model.yaml')
    assert loaded.c_d_spin_ratio_slope == 0.25
    assert loaded.active_effects() == ['c_d_spin_ratio_slope']
    assert ModelParams.from_packed(params.packed()) == params


def test_integrator_applies_spin_dependent_drag():
    # A backspin ball flying towards -x: more drag leaves it short of the nominal path.
    state = np.array([1.2, 0.0, 0.3, -5.0, 0.0, 1.0, 0.0, 300.0, 0.0])
    times = np.array([0.5])
    _, plain = rollout(state, ModelParams(), sample_times=times, stop_at_net=False)
    _, spun = rollout(state, ModelParams(c_d_spin_ratio_slope=0.5), sample_times=times,
                      stop_at_net=False)
    ratio = 0.02 * 300.0 / np.linalg.norm(state[3:6])       # 1.18 > 0.3: C_D grows
    assert ratio > LIFT_SPIN_RATIO_REF
    assert spun[0, 0] > plain[0, 0] + 0.01
