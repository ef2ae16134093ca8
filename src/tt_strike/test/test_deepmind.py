"""The strike solver over a sample of measured ball states (DeepMind, CC BY 4.0; see
data/deepmind_states/README.md): the issue's table on 100 of the 15,792 states."""

import pathlib

import numpy as np
from tt_prediction.params import ModelParams
from tt_strike.evaluate_deepmind import evaluate, load_states, main
from tt_strike.solver import StrikeSettings

DATA = pathlib.Path(__file__).resolve().parents[3] / 'data' / 'deepmind_states'


def test_states_are_turned_towards_the_robot():
    states, serve, away = load_states(DATA / 'states.csv')
    assert states.shape == (100, 9)
    assert np.all(states[:, 3] < 0.0)               # every ball now moves towards x < 0
    assert 0 < away.sum() < len(states)              # some were hit from the robot's end
    assert serve.sum() > 0
    # a serve starts behind the opponent's end line
    assert np.all(states[serve, 0] > 1.0)


def test_every_feasible_solution_lands_in_its_zone():
    states, serve, _ = load_states(DATA / 'states.csv')
    rows, skipped, n_hits, _ = evaluate(states, serve, ModelParams(), StrikeSettings())
    assert n_hits + sum(skipped.values()) == len(states)
    assert n_hits >= 70
    for row in rows:
        # Some of these balls are struck below the table's surface at x = -1.5, and the
        # table as a body turns a return through its end face into a miss: 0.95 before.
        assert row['feasible_share'] >= 0.90, row
        assert row['in_zone_share'] == 1.0, row
        assert row['residual_max_mm'] < 5.0, row


def test_command_writes_the_table(tmp_path, capsys):
    out = tmp_path / 'table.json'
    assert main(['--data', str(DATA), '--limit', '20', '--json', str(out)]) == 0
    text = capsys.readouterr().out
    assert '| zone | balls |' in text and out.is_file()


def test_missing_data_is_a_one_line_error(tmp_path, capsys):
    assert main(['--data', str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert 'no states.csv' in err and err.count('\n') == 1

