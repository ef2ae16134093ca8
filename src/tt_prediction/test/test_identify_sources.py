"""Which track files a data set holds and how its tracks are named, in tt-identify (load) and
tt-predict --tracks (read_tracks): a track is counted once, named uniquely, and a .CSV is a
track file as much as a .csv."""

import os

import pytest
from tt_prediction.identify.cli import main
from tt_prediction.identify.data import DataError, load
from tt_prediction.tracks_cli import read_tracks

TRACK = 't,x,y,z\n0,0,0,0.3\n0.01,0.05,0,0.3\n0.02,0.1,0,0.3\n'


def _folder(path, names, index=None):
    path.mkdir(parents=True)
    for name in names:
        (path / name).write_text(TRACK)
    if index is not None:
        (path / 'index.csv').write_text(index)
    return path


def test_the_same_folder_given_twice_is_refused_in_one_line(tmp_path, capsys):
    # Given twice, 4 tracks counted as 8: past the 8-track minimum of effect selection, and
    # a track's copy in the training folds of its own held-out fold.
    data = _folder(tmp_path / 'four', ['a.csv', 'b.csv'])
    os.symlink(data, tmp_path / 'link')
    for second in (str(data), str(data) + '/', str(tmp_path / 'link')):
        with pytest.raises(DataError, match='given twice'):
            load([str(data), second])
    out = tmp_path / 'out'
    code = main([str(data), str(data), '--out', str(out), '--no-progress'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and 'given twice' in err[0]
    assert not out.exists()


def test_folders_with_the_same_base_name_give_distinct_track_names(tmp_path):
    a = _folder(tmp_path / 'a' / 'sim', ['0000.csv'])
    b = _folder(tmp_path / 'b' / 'sim', ['0000.csv'])
    names = [tr.name for tr in load([str(a), str(b)])]
    assert names == ['a/sim/0000.csv', 'b/sim/0000.csv']
    assert [tr.name for tr in load([str(a)])] == ['sim/0000.csv']


@pytest.mark.parametrize('cwd, given', [('sim', '.'), ('sim', './'), ('.', 'sim/../sim'),
                                       ('sim', '../sim')])
def test_a_folder_given_as_a_relative_path_names_its_tracks_by_its_own_name(tmp_path,
                                                                             monkeypatch,
                                                                             cwd, given):
    # '.' named 0000.csv and 1000.csv both 'sim000.csv' (the name cut at the length of the
    # folder's absolute name).
    _folder(tmp_path / 'sim', ['0000.csv', '1000.csv'])
    monkeypatch.chdir(tmp_path / cwd)
    assert [tr.name for tr in load([given])] == ['sim/0000.csv', 'sim/1000.csv']


def test_upper_case_csv_files_are_track_files_in_both_readers(tmp_path):
    names = ['0000.CSV', '0001.csv', '0002.Csv']
    plain = _folder(tmp_path / 'plain', names)
    indexed = _folder(tmp_path / 'indexed', names,
                      index='file,wx,wy,wz\n0000.CSV,0,0,100\n0001.csv,,,\n')
    for folder in (plain, indexed):
        assert sorted(name for name, *_ in read_tracks(str(folder))) == sorted(names)
        assert len(load([str(folder)])) == 3
    spin = {name: s for name, _, _, s in read_tracks(str(indexed))}
    assert spin['0000.CSV'][2] == 100.0
