"""The library of candidate effects: physical mechanisms the paper's model leaves out.

Each effect is one mechanism with one or two global parameters (see fitting.GLOBAL_BOUNDS
for their ranges and tt_prediction.params for the equations they enter). The model's effects
are declared once, in tt_prediction.params (FIELDS, EFFECTS). Model physics lives
in ModelParams (so that the prediction and strike nodes use it through model.yaml); the
spin bias belongs to the measurement model. An effect may not apply to a data set: table
effects need bounces, the spin bias needs measured spin; a constant time offset between the
measurement clock and the model only shifts each track's fitted initial state, so positions
alone cannot identify it and it is reported as not identifiable rather than fitted.
"""

from ..ball import EFFECTS, Effect

MODEL_EFFECTS = EFFECTS
"""The model's effects, as declared in tt_prediction.params.EFFECTS (model.yaml)."""

LIBRARY = MODEL_EFFECTS + (
    Effect('spin_measurement_bias', ('spin_scale',),
           'measured spin is off by a scale: w_true = (1 + spin_scale) w_measured',
           needs='spin'),
    Effect('time_offset', (),
           'measurement time stamps lag the model clock by a constant'),
    Effect('lift_from_bounces', ('c_m',),
           'Magnus coefficient C_M differs from the nominal value; with spin not measured it '
           "is told apart from each track's spin only by the table rebound, which turns the "
           'spin itself (eqs. 1-2, r w) into velocity while the flight sees C_M w (eq. 8)',
           needs='bounces_no_spin'),
    Effect('gravity_or_scale', ('gravity',),
           'gravity, or equivalently a position-scale error of the calibration '
           '(g_apparent = s g) or stamps from a clock running fast by e (g_apparent = '
           'g / (1 + e)^2), differs from 9.8 m/s^2'),
)
"""Every candidate effect: the model's, then those of the measurement (spin bias, time
offset) and of the calibration (gravity or scale)."""

NOT_IDENTIFIABLE = {
    'time_offset': "a constant offset of all time stamps shifts each track's fitted initial "
                   'state in time and leaves every residual unchanged: not identifiable from '
                   'positions (gain 0 by construction); needs an external time reference',
}


MIN_TRACKS = 8
"""Fewest usable tracks on which an effect is selected: held-out gains over fewer tracks (a
few folds of one or two tracks each) are not evidence of a mechanism."""
MIN_BOUNCES = 8
"""Fewest located table bounces on which a table effect is tested."""
MIN_SPIN_TRACKS = 8
"""Fewest tracks with measured spin on which a spin-measurement effect is tested."""


def too_small(n_tracks):
    """Why the data is too small to select any effect, or '' when it is not."""
    if n_tracks < MIN_TRACKS:
        return (f'data too small to select an effect: {n_tracks} usable tracks, at least '
                f'{MIN_TRACKS} are needed; nothing selected')
    return ''


def applicable(effect, n_bounces, n_spin):
    """Why an effect cannot be tested on this data, or '' when it can. ``n_bounces``: table
    bounces located in the data; ``n_spin``: tracks with measured (not estimated) spin."""
    if effect.name in NOT_IDENTIFIABLE:
        return NOT_IDENTIFIABLE[effect.name]
    if effect.needs == 'bounces' and n_bounces < MIN_BOUNCES:
        return (f'{n_bounces} table bounces in the data, at least {MIN_BOUNCES} needed'
                if n_bounces else 'no table bounce in the data')
    if effect.needs == 'bounces_no_spin':
        if n_spin:
            return (f'measured spin on {n_spin} tracks: C_M is fitted in the baseline '
                    '(eq. 9)')
        if n_bounces < MIN_BOUNCES:
            return (f'{n_bounces} table bounces in the data, at least {MIN_BOUNCES} needed: '
                    'without measured spin only bounces separate C_M from spin'
                    if n_bounces else 'no table bounce and no measured spin: C_M and spin '
                                      'are not separately identifiable')
        return ''
    if effect.needs == 'spin' and n_spin < MIN_SPIN_TRACKS:
        return (f'measured spin on {n_spin} tracks, at least {MIN_SPIN_TRACKS} needed'
                if n_spin else 'no measured spin in the data (index.csv; estimated spin '
                               'does not count)')
    return ''
