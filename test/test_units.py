"""Wrong units are refused (issue 17 item 5): positions outside the room (a coordinate beyond
10 m, e.g. a table in millimetres) in tt-predict's and tt-identify's input, and a rig
translation in millimetres (tt-perceive, perception_node), each give one line naming the file
and the field, exit 2."""

import json
import subprocess

import numpy as np
import pytest
from tt_perception.camera import CalibrationError, load_rig
from tt_prediction.identify.data import clean_samples, read_track_csv
from tt_prediction.units import outside_room, position_error, translation_error
from tt_tools.procs import ros_env

TABLE_MM = [1600.0, 100.0, 300.0]       # a ball over the table, written in millimetres


def _run(argv, stdin=''):
    proc = subprocess.run(argv, input=stdin, capture_output=True, text=True, env=ros_env(),
                          timeout=120)
    return proc.returncode, proc.stdout, proc.stderr.strip().splitlines()


@pytest.mark.parametrize('p, bad', [
    ([1.6, 0.1, 0.3], False),
    ([-10.0, 10.0, -10.0], False),       # the room's edge is still in it
    ([10.01, 0.0, 0.0], True),
    (TABLE_MM, True),
    ([[0.0, 0.0, 0.2], [0.1, 0.0, 0.2], [0.0, -1525.0, 0.2]], True),
])
def test_position_error_is_beyond_ten_metres(p, bad):
    assert bool(position_error(p)) == bad


def test_position_error_names_the_field_and_the_first_bad_row():
    text = position_error([[0.0, 0.0, 0.2], [0.0, -1525.0, 0.2]], 'x, y, z')
    assert text.startswith('x, y, z = [0, -1525, 0.2] (row 2): outside the room')
    assert 'millimetres' in text
    # A track in centimetres (a ball 1.5 m out: 150) was told only of millimetres.
    assert 'centimetres' in position_error([150.0, 10.0, 30.0])


def test_a_track_is_judged_on_most_of_its_rows():
    """One stereo mismatch 12 m away refused a whole data set as millimetres, naming 'row
    49' for the file's line 50 (a researcher's walk-through, 6 Dec 2026): a track is in
    millimetres when most of its rows are outside the room, and its line is named."""
    track = np.array([[1.6 - 0.06 * k, 0.1, 0.3] for k in range(10)])
    track[3] = [12.5, 0.1, 0.3]
    assert position_error(track, 'x, y, z', most=True) == ''
    assert outside_room(track).tolist() == [k == 3 for k in range(10)]
    track[:6] *= 1000.0                    # six of ten rows in millimetres
    text = position_error(track, 'x, y, z', most=True, lines=range(2, 12))
    assert text.startswith('x, y, z = [1600, 100, 300] (line 2): outside the room')


def test_a_wild_sample_is_dropped_and_counted_by_both_commands(tmp_path):
    data = tmp_path / 'tracks'
    data.mkdir()
    t = np.arange(30) / 100.0
    rows = ['t,x,y,z'] + [f'{ti},{1.6 - 6 * ti},{0.1},{0.3 + ti - 4.9 * ti * ti}' for ti in t]
    rows[11] = f'{t[10]},12.5,0.1,0.3'
    (data / 'track1.csv').write_text('\n'.join(rows) + '\n')
    tt, p = read_track_csv(str(data / 'track1.csv'))
    assert len(tt) == 30
    tc, pc, notes = clean_samples('track1', tt, p)
    assert notes == {'outside_room_rows': 1} and len(tc) == 29 and np.all(np.abs(pc) < 10.0)
    code, out, err = _run(['tt-predict', '--tracks', str(data), '--out', str(tmp_path / 'out'),
                           '--no-textbook'])
    assert code == 0, err
    written = np.genfromtxt(tmp_path / 'out' / 'track1.csv', delimiter=',', names=True)
    assert len(written) == 30 and np.nanmax(np.abs(written['x'])) < 10.0


def test_translation_error_is_a_camera_beyond_twenty_metres():
    # |t| is the camera centre's distance from the origin whatever the rotation.
    assert translation_error([0.3, 0.19, 3.6]) == ''
    assert translation_error([0.0, 12.0, 16.0]) == ''          # exactly 20 m
    assert 'metres, not millimetres' in translation_error([300.0, 191.0, 3620.0])


def test_tt_predict_refuses_a_state_in_millimetres(tmp_path):
    line = json.dumps({'t': 0.0, 'p': TABLE_MM, 'v': [-6.0, 0.0, 1.5], 'w': [0, 0, 0]})
    path = tmp_path / 'states.jsonl'
    path.write_text(json.dumps({'t': 0.0, 'p': [1.6, 0.1, 0.3], 'v': [-6.0, 0.0, 1.5],
                                'w': [0, 0, 0]}) + '\n' + line + '\n')
    code, out, err = _run(['tt-predict', '--input', str(path)])
    assert code == 2 and out == '' and len(err) == 1
    assert err[0].startswith(f'tt-predict: {path}: line 2: "p" = [1600, 100, 300]: outside')


def test_tt_identify_refuses_a_track_in_millimetres(tmp_path):
    data = tmp_path / 'tracks'
    data.mkdir()
    t = np.arange(10) / 100.0
    rows = ['t,x,y,z'] + [f'{ti},{1600 - 6000 * ti},{100},{300 + 1000 * ti}' for ti in t]
    (data / 'track1.csv').write_text('\n'.join(rows) + '\n')
    code, _, err = _run(['tt-identify', str(data), '--out', str(tmp_path / 'out')])
    assert code == 2 and len(err) == 1
    assert err[0].startswith(f'tt-identify: {data / "track1.csv"}: x, y, z = [1600, 100, 300]')
    assert not (tmp_path / 'out').exists() or not any((tmp_path / 'out').iterdir())


def test_tt_predict_tracks_refuses_a_track_in_millimetres(tmp_path):
    data = tmp_path / 'tracks'
    data.mkdir()
    t = np.arange(10) / 100.0
    rows = ['t,x,y,z'] + [f'{ti},{1600 - 6000 * ti},{100},{300 + 1000 * ti}' for ti in t]
    (data / 'track1.csv').write_text('\n'.join(rows) + '\n')
    code, _, err = _run(['tt-predict', '--tracks', str(data), '--out', str(tmp_path / 'out')])
    assert code == 2 and len(err) == 1, err
    assert f'{data / "track1.csv"}: x, y, z = [1600, 100, 300]' in err[0]
    assert not (tmp_path / 'out').exists()


def _rig_in_mm(tmp_path):
    from tt_perception import synth

    rig_path = synth.make_rig(str(tmp_path / 'calib'))
    rig = load_rig(rig_path)
    for cam in rig.cameras:
        cam.t = cam.t * 1000.0
    import yaml

    with open(rig_path) as f:
        data = yaml.safe_load(f)
    for entry, cam in zip(data['cameras'], rig.cameras, strict=True):
        entry['translation'] = [float(v) for v in cam.t]
    with open(rig_path, 'w') as f:
        yaml.safe_dump(data, f)
    return rig_path


def test_a_rig_in_millimetres_is_refused_naming_the_file_and_field(tmp_path):
    rig_path = _rig_in_mm(tmp_path)
    with pytest.raises(CalibrationError) as err:
        load_rig(rig_path)
    text = str(err.value)
    assert '\n' not in text
    assert text.startswith(f'rig {rig_path}: cameras[0] (cam0): translation [')
    assert 'not millimetres' in text
    code, _, lines = _run(['tt-perceive', '--rig', rig_path, '--out', str(tmp_path / 'out')])
    assert code == 2 and len(lines) == 1 and 'cameras[0] (cam0): translation' in lines[0]
