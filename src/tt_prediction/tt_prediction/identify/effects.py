"""The library of candidate effects: physical mechanisms the paper's model leaves out.

Each effect is one mechanism with one or two global parameters (see fitting.GLOBAL_BOUNDS
for their ranges and tt_prediction.params for the equations they enter). Model physics lives
in ModelParams (so that the prediction and strike nodes use it through model.yaml); the
spin bias belongs to the measurement model. An effect may not apply to a data set: table
effects need bounces, the spin bias needs measured spin; a constant time offset between the
measurement clock and the model only shifts each track's fitted initial state, so positions
alone cannot identify it and it is reported as not identifiable rather than fitted.
"""

import dataclasses


@dataclasses.dataclass(frozen=True)
class Effect:
    """One candidate effect: its name, the globals it frees, and what it means."""

    name: str
    params: tuple
    mechanism: str
    needs: str = ''
    """'bounces' (table effects), 'spin' (measured spin), or '' (any flight data)."""


LIBRARY = (
    Effect('spin_decay', ('spin_decay',),
           'air friction slows the spin in flight: dw/dt = -spin_decay w (1/s)'),
    Effect('wind', ('wind_x', 'wind_y'),
           'a steady horizontal air draft (m/s): drag and lift act on v - wind'),
    Effect('drag_reynolds', ('c_d_speed_slope',),
           'drag coefficient varies with air speed (Reynolds number): '
           'C_D = c_d + slope (|v| - 6 m/s)'),
    Effect('drag_spin', ('c_d_spin_ratio_slope',),
           'drag coefficient varies with the spin ratio (the spinning boundary layer): '
           'C_D = c_d + slope (r|w|/|v| - 0.3)'),
    Effect('lift_spin_ratio', ('c_m_spin_ratio_slope',),
           'Magnus coefficient varies with the spin ratio: C_M = c_m + slope (r|w|/|v| - 0.3)'),
    Effect('table_restitution_speed', ('e_t_speed_slope',),
           'table restitution falls with impact speed: e_t = e_t + slope (|v_z| - 3 m/s)',
           needs='bounces'),
    Effect('table_friction_spin', ('mu_spin_slope',),
           'table friction varies with spin: mu = mu + slope |w|', needs='bounces'),
    Effect('spin_measurement_bias', ('spin_scale',),
           'measured spin is off by a scale: w_true = (1 + spin_scale) w_measured',
           needs='spin'),
    Effect('time_offset', (),
           'measurement time stamps lag the model clock by a constant'),
    Effect('gravity_or_scale', ('gravity',),
           'gravity, or equivalently a position-scale error of the calibration '
           '(g_apparent = s g), differs from 9.8 m/s^2'),
)

NOT_IDENTIFIABLE = {
    'time_offset': "a constant offset of all time stamps shifts each track's fitted initial "
                   'state in time and leaves every residual unchanged: not identifiable from '
                   'positions (gain 0 by construction); needs an external time reference',
}


def applicable(effect, has_bounces, has_spin):
    """Why an effect cannot be tested on this data, or '' when it can."""
    if effect.name in NOT_IDENTIFIABLE:
        return NOT_IDENTIFIABLE[effect.name]
    if effect.needs == 'bounces' and not has_bounces:
        return 'no table bounce in the data'
    if effect.needs == 'spin' and not has_spin:
        return 'no measured spin in the data (index.csv)'
    return ''
