"""tt-identify on measured-looking synthetic data with a planted effect (or none).

The data are generated with the model plus one effect that the baseline model does not
declare, 150 Hz, 1.5 mm noise, drop-outs, outliers of 3 to 8 cm, stamp jitter. The tool
must select that effect alone, recover its parameter within the stated tolerance, and at
least halve the held-out hit-plane error; on clean data it must select nothing.
"""

import json

import pytest
from tt_prediction.identify.cli import main
from tt_prediction.identify.pipeline import identify
from tt_prediction.identify.synthetic import make_tracks
from tt_prediction.params import PACKED_FIELDS, ModelParams

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
