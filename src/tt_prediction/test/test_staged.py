"""staged_folder: an output folder is replaced as a whole, or, where it cannot be swapped
(a mount point, a parent that takes no new folder), its files are, once all are written."""

import errno
import os
import re
import tempfile

import pytest
from tt_prediction.staged import staged_folder

from tt_prediction import staged


def _earlier_output(tmp_path):
    out = tmp_path / 'out'
    out.mkdir()
    (out / 'old.csv').write_text('old\n')
    (out / 'summary.json').write_text('{"old": 1}\n')
    return out


def _write_new(folder):
    with open(os.path.join(folder, 'summary.json'), 'w') as f:
        f.write('{"new": 1}\n')
    with open(os.path.join(folder, 'new.csv'), 'w') as f:
        f.write('new\n')


def _holds_only_the_new_output(out):
    assert sorted(p.name for p in out.iterdir()) == ['new.csv', 'summary.json']
    assert (out / 'summary.json').read_text() == '{"new": 1}\n'


def test_an_earlier_output_is_replaced_as_a_whole(tmp_path):
    out = _earlier_output(tmp_path)
    with staged_folder(out, 'tool') as tmp:
        _write_new(tmp)
    _holds_only_the_new_output(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out']      # no holder left


def test_a_mount_point_keeps_its_place_and_gets_the_new_files(tmp_path, monkeypatch):
    """A mount point cannot be renamed (EBUSY): a new user's walk-through gave one as --out."""
    out = _earlier_output(tmp_path)
    out.chmod(0o750)
    inode = out.stat().st_ino
    is_mount = os.path.ismount
    monkeypatch.setattr(os.path, 'ismount', lambda p: p == str(out) or is_mount(p))
    with staged_folder(out, 'tool') as tmp:
        _write_new(tmp)
    _holds_only_the_new_output(out)
    assert out.stat().st_ino == inode
    assert out.stat().st_mode & 0o777 == 0o750
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out']


def test_a_folder_that_cannot_be_renamed_gets_the_new_files(tmp_path, monkeypatch):
    """A bind mount is busy although ismount does not see it: the rename's error is caught."""
    out = _earlier_output(tmp_path)
    rename = os.rename

    def busy(src, dst):
        if os.fspath(src) == str(out):
            raise OSError(errno.EBUSY, os.strerror(errno.EBUSY), src)
        return rename(src, dst)

    monkeypatch.setattr(os, 'rename', busy)
    with staged_folder(out, 'tool') as tmp:
        _write_new(tmp)
    _holds_only_the_new_output(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out']


def _parent_takes_no_folder(tmp_path, monkeypatch):
    mkdtemp = tempfile.mkdtemp

    def denied(*args, dir=None, **kwargs):
        if dir == str(tmp_path):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), dir)
        return mkdtemp(*args, dir=dir, **kwargs)

    monkeypatch.setattr(staged.tempfile, 'mkdtemp', denied)


def test_a_parent_that_takes_no_folder_stages_inside_the_output(tmp_path, monkeypatch):
    out = _earlier_output(tmp_path)
    _parent_takes_no_folder(tmp_path, monkeypatch)
    with staged_folder(out, 'tool') as tmp:
        assert os.path.dirname(os.path.dirname(tmp)) == str(out)
        _write_new(tmp)
    _holds_only_the_new_output(out)


def test_an_error_in_place_leaves_the_earlier_output(tmp_path, monkeypatch):
    out = _earlier_output(tmp_path)
    _parent_takes_no_folder(tmp_path, monkeypatch)
    with pytest.raises(RuntimeError), staged_folder(out, 'tool') as tmp:
        _write_new(tmp)
        raise RuntimeError('failed half-way')
    assert sorted(p.name for p in out.iterdir()) == ['old.csv', 'summary.json']
    assert (out / 'summary.json').read_text() == '{"old": 1}\n'


def test_a_missing_output_under_a_parent_that_takes_no_folder_is_an_error(tmp_path,
                                                                         monkeypatch):
    _parent_takes_no_folder(tmp_path, monkeypatch)
    with pytest.raises(PermissionError), staged_folder(tmp_path / 'out', 'tool'):
        pass
    assert not (tmp_path / 'out').exists()


def test_in_place_no_file_is_lost_when_a_rename_fails(tmp_path, monkeypatch):
    # The old files were removed before the new ones were moved in: a full disk (a 64 KB
    # tmpfs) left 3 of 8 new rows, a 0-byte params.yaml and neither output (a review).
    out = _earlier_output(tmp_path)
    is_mount = os.path.ismount
    monkeypatch.setattr(os.path, 'ismount', lambda p: p == str(out) or is_mount(p))
    replace = os.replace

    def failing(src, dst):          # the second of the two new files (in name order)
        if dst.endswith('summary.json'):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), dst)
        return replace(src, dst)

    monkeypatch.setattr(os, 'replace', failing)
    monkeypatch.setattr(staged.shutil, 'move', lambda src, dst: failing(src, dst))
    with pytest.raises(OSError), staged_folder(out, 'tool') as tmp:
        _write_new(tmp)
    names = sorted(p.name for p in out.iterdir())
    assert {'old.csv', 'summary.json'} <= set(names) and not any(n.startswith('.') for n in names)
    assert (out / 'old.csv').read_text() == 'old\n'
    assert (out / 'summary.json').read_text() == '{"old": 1}\n'
    assert (out / 'new.csv').read_text() == 'new\n'              # the one renamed before


def test_a_holder_a_killed_run_left_in_the_output_is_taken_and_removed(tmp_path, monkeypatch):
    # Killed (SIGKILL) while staging inside its output, a run left .tt-tool-XXXX there, and
    # the next run refused the folder as holding something not its own.
    out = _earlier_output(tmp_path)
    (out / '.tt-tool-abc123' / 'new').mkdir(parents=True)
    assert staged.output_folder_error(str(out), re.compile(r'.+\.csv|summary\.json'),
                                      'tool') == ''
    _parent_takes_no_folder(tmp_path, monkeypatch)
    with staged_folder(out, 'tt-tool') as tmp:
        _write_new(tmp)
    _holds_only_the_new_output(out)


@pytest.mark.parametrize('sig_name', ['SIGINT', 'SIGTERM'])
def test_a_command_stopped_while_it_stages_leaves_the_earlier_output_alone(tmp_path,
                                                                           sig_name):
    # `timeout` and batch systems stop a command with SIGTERM: it ended tt-identify at once
    # and left its hidden staging folder, half written, beside --out (a walk-through,
    # 7 Dec 2026). Through tt_ros.entry.run, as every console script starts, it is a
    # Ctrl-C: one line, status 130, the earlier output as it was and no holder left.
    import signal
    import subprocess
    import sys
    out = _earlier_output(tmp_path)
    (tmp_path / 'stager.py').write_text(
        'import threading\n'
        'from tt_prediction.staged import staged_folder\n'
        'def main():\n'
        f'    with staged_folder({str(out)!r}, "tool") as tmp:\n'
        '        open(tmp + "/summary.json", "w").write("{}")\n'
        '        print("staged", flush=True)\n'
        '        threading.Event().wait()\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path)] + sys.path))
    proc = subprocess.Popen(
        [sys.executable, '-c', "import sys; from tt_ros.entry import run; "
                               "sys.exit(run('stager:main', 'tool'))"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert proc.stdout.readline() == 'staged\n'
    proc.send_signal(getattr(signal, sig_name))
    _, err = proc.communicate(timeout=30)
    assert (proc.returncode, err) == (130, 'tool: interrupted\n')
    assert sorted(p.name for p in tmp_path.iterdir()) in (['out', 'stager.py'],
                                                        ['__pycache__', 'out', 'stager.py'])
    assert sorted(p.name for p in out.iterdir()) == ['old.csv', 'summary.json']
