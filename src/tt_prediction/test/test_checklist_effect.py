"""docs/DEVELOPING.md, "Checklist: adding a model effect": this test fails when a step is
forgotten for any effect declared in tt_prediction.params (FIELDS, EFFECTS)."""

import pathlib
import re

import numpy as np
import pytest
from tt_prediction.ball_filter import rebound_jacobian
from tt_prediction.identify.effects import LIBRARY

from tt_prediction import ball, params

DOCS = pathlib.Path(__file__).resolve().parents[3] / 'docs'
EFFECT_FIELDS = [f for f in ball.FIELDS if f.effect]


def _on(field):
    """A non-zero value inside the field's plausible range."""
    lo, hi = field.bounds
    v = 0.5 * hi if hi > 0 else 0.5 * lo
    return (v,) * len(field.default) if isinstance(field.default, tuple) else v


def _states(rng, n=40):
    s = np.empty((n, 9))
    s[:, :3] = rng.uniform(-1, 1, (n, 3))
    s[:, 3:6] = rng.uniform(-8, 8, (n, 3))
    s[:, 5] = -np.abs(s[:, 5]) - 0.5             # moving down: a valid table contact
    s[:, 6:9] = rng.uniform(-500, 500, (n, 3))
    return s


def test_every_declared_effect_has_a_row_in_the_identification_docs():
    text = (DOCS / 'identification.md').read_text()
    rows = set(re.findall(r'^\| `([a-z_]+)` \|', text, flags=re.M))
    missing = [e.name for e in ball.EFFECTS if e.name not in rows]
    assert not missing, f'docs/identification.md effect table lacks {missing}'


def test_the_checklist_names_the_files_it_asks_to_touch():
    text = (DOCS / 'DEVELOPING.md').read_text()
    section = text.split('## Checklist: adding a model effect')[1].split('\n## ')[0]
    root = DOCS.parent
    for path in re.findall(r'`((?:src|docs)/[^`]+\.(?:py|md))`', section):
        assert (root / path).exists(), f'DEVELOPING.md names a missing file {path}'
    for name in ('params.py', 'model.py', 'ball.py', 'identification.md'):
        assert name in section


@pytest.mark.parametrize('field', EFFECT_FIELDS, ids=[f.name for f in EFFECT_FIELDS])
def test_effect_field_is_declared_completely(field):
    # Off by default (the paper's model), a unit, a plausible range that holds 0.
    values = field.default if isinstance(field.default, tuple) else (field.default,)
    assert all(v == 0.0 for v in values)
    assert field.unit and field.doc
    assert field.bounds[0] <= 0.0 <= field.bounds[1] and field.bounds[0] < field.bounds[1]
    # In identify's library with the same slots, each with its fit range.
    (effect,) = [e for e in ball.EFFECTS if e.name == field.effect]
    (entry,) = [e for e in LIBRARY if e.name == effect.name]
    assert tuple(entry.slots) == tuple(effect.slots)
    # The effect frees slots of its own fields (one, or several: gravity_x, gravity_y).
    own = {slot for f in EFFECT_FIELDS if f.effect == effect.name for slot in f.slots}
    assert set(effect.slots) <= own and set(effect.slots) & set(field.slots)
    # An I_* constant for each slot, exported by tt_prediction.ball.
    for slot in field.slots:
        names = [n for n in dir(params) if n.startswith('I_')
                 and getattr(params, n) == ball.INDEX[slot]]
        assert names, f'no I_* constant for {slot} in params.py'
        assert any(n in ball.__all__ for n in names), f'{names} not in ball.__all__'


@pytest.mark.parametrize('field', EFFECT_FIELDS, ids=[f.name for f in EFFECT_FIELDS])
def test_effect_changes_the_model_when_switched_on(field):
    P0 = ball.ModelParams().packed()
    P1 = ball.ModelParams(**{field.name: _on(field)}).packed()
    rng = np.random.default_rng(4)
    flight_changed = rebound_changed = racket_changed = False
    a0, a1 = np.empty(9), np.empty(9)
    normal = np.array([0.6, 0.0, 0.8])
    for s in _states(rng):
        ball.flight_derivative(s, P0, a0)
        ball.flight_derivative(s, P1, a1)
        flight_changed |= not np.allclose(a0, a1, rtol=1e-12, atol=0)
        r0, r1 = s.copy(), s.copy()
        ball.table_rebound_inplace(r0, P0)
        ball.table_rebound_inplace(r1, P1)
        rebound_changed |= not np.allclose(r0, r1, rtol=1e-12, atol=0)
        r0, r1 = s.copy(), s.copy()
        racket = np.array([1.5, 0.2, 0.5])
        ball.racket_rebound_inplace(r0, P0, normal, racket)
        ball.racket_rebound_inplace(r1, P1, normal, racket)
        racket_changed |= not np.allclose(r0, r1, rtol=1e-12, atol=0)
    assert flight_changed or rebound_changed or racket_changed, (
        f'{field.name} changes nothing in model.py')
    # A table effect is tested by tt-identify only on data that bounce (the checklist's
    # needs='bounces'); forgotten, it was tested on flights it cannot act on.
    (effect,) = [e for e in ball.EFFECTS if e.name == field.effect]
    if rebound_changed and not flight_changed:
        assert effect.needs == 'bounces', f'{effect.name}: a table effect without needs'
    if flight_changed:
        # The Jacobian of eq. 8 must carry the effect too (central differences).
        for s in _states(rng, 5):
            J = ball.flight_jacobian(s, P1, np.empty((9, 9)))
            num = np.empty((9, 9))
            fp, fm = np.empty(9), np.empty(9)
            for j in range(9):
                h = 1e-6 * max(1.0, abs(s[j]))
                sp, sm = s.copy(), s.copy()
                sp[j] += h
                sm[j] -= h
                ball.flight_derivative(sp, P1, fp)
                ball.flight_derivative(sm, P1, fm)
                num[:, j] = (fp - fm) / (2 * h)
            np.testing.assert_allclose(J, num, rtol=1e-5, atol=1e-6 * np.abs(num).max())
    if rebound_changed:
        # The filters' Jacobian of eqs. 1-6 must carry it too (central differences; in the
        # middle of the table, by either end line and either side line).
        for x, y in ((-0.5, 0.1), (-1.31, 0.1), (-0.9, -0.72), (1.31, 0.1), (0.9, 0.72)):
            s = np.array([x, y, 0.02, -4.0, 0.5, -3.0, 25.0, -150.0, 50.0])
            J = np.empty((9, 9))
            rebound_jacobian(s, P1, J)
            num = np.empty((9, 9))
            for j in range(9):
                h = 1e-6 * max(1.0, abs(s[j]))
                sp, sm = s.copy(), s.copy()
                sp[j] += h
                sm[j] -= h
                ball.table_rebound_inplace(sp, P1)
                ball.table_rebound_inplace(sm, P1)
                num[:, j] = (sp - sm) / (2 * h)
            np.testing.assert_allclose(J, num, rtol=1e-5, atol=1e-6 * np.abs(num).max())
