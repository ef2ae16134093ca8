"""Console scripts start through :func:`tt_ros.entry.run`: a Ctrl-C during their imports ends
with one line and status 130, and each names the executable it is and a function that exists.
"""

import ast
import configparser
import os
import pathlib
import signal
import subprocess
import sys
import textwrap

import pytest

SRC = pathlib.Path(__file__).resolve().parents[2]
HEAVY = ('numpy', 'scipy', 'numba', 'cv2', 'rclpy', 'yaml')


def console_scripts():
    """(package dir, executable, 'module:function') of every console script in src/*."""
    found = []
    for cfg in sorted(SRC.glob('*/setup.cfg')):
        parser = configparser.ConfigParser()
        parser.read(cfg)
        lines = parser.get('options.entry_points', 'console_scripts', fallback='')
        for line in filter(None, (s.strip() for s in lines.splitlines())):
            exe, _, target = (s.strip() for s in line.partition('='))
            found.append((cfg.parent, exe, target))
    return found


NODE_AND_CLI_SCRIPTS = console_scripts()
QUIET_COMMANDS = ('ros2', 'bringup')
"""Commands that, as a node, stop quietly when interrupted while importing: ros2 (as
ros2cli before a verb has started) and bringup (a graph that had not started). They had no
guard at all: a Ctrl-C in their first 0.1-0.25 s gave a traceback (a walk-through, 6 Dec
2026)."""


def _sigint_as_from_a_terminal():
    # A test run started in the background by a non-interactive shell (`make test &`)
    # ignores SIGINT, and so would the child: Python then installs no KeyboardInterrupt
    # handler. A process run from a terminal, as these tests mean, has the default.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def python(code, tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path)] + sys.path))
    return subprocess.Popen([sys.executable, '-c', code], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_sigint_as_from_a_terminal)


def test_ctrl_c_while_importing_is_one_line_and_status_130(tmp_path):
    # The target announces that its import has begun, then blocks in it (as numba's would).
    (tmp_path / 'slow_import.py').write_text(textwrap.dedent("""\
        import sys, threading
        print('importing', flush=True)
        threading.Event().wait()
        def main():
            return 0
    """))
    proc = python('import sys; from tt_ros.entry import run; '
                  "sys.exit(run('slow_import:main', 'slow_tool'))", tmp_path)
    assert proc.stdout.readline() == 'importing\n'
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130
    assert err == 'slow_tool: interrupted\n'


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_node_interrupted_while_importing_stops_cleanly(tmp_path, sig):
    # As run_node ends on SIGINT or SIGTERM: status 0, nothing said (bringup's Ctrl-C while
    # it starts; a SIGTERM killed a node still importing, status -15).
    (tmp_path / 'slow_node.py').write_text(
        "import threading\nprint('importing', flush=True)\nthreading.Event().wait()\n")
    proc = python('import sys; from tt_ros.entry import run; '
                  "sys.exit(run('slow_node:main', 'slow_node', quiet=True))", tmp_path)
    assert proc.stdout.readline() == 'importing\n'
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=30)
    assert (proc.returncode, err) == (0, '')


@pytest.mark.parametrize('quiet, status, said', [(False, 130, 'cut: interrupted\n'),
                                                 (True, 0, '')])
def test_an_import_cut_by_ctrl_c_is_an_interruption_not_a_traceback(tmp_path, quiet, status,
                                                                    said):
    # A pybind11 module (rclpy's) whose initialisation a Ctrl-C cuts raises ImportError
    # "initialization failed" from the KeyboardInterrupt: a traceback and status 1 from a
    # node interrupted 0.8 s into its start (a walk-through, 6 Dec 2026). Any other
    # ImportError is still one.
    (tmp_path / 'cut.py').write_text(
        "raise ImportError('initialization failed') from KeyboardInterrupt()\n")
    (tmp_path / 'broken.py').write_text("raise ImportError('no module named nothing')\n")
    proc = python('import sys; from tt_ros.entry import run; '
                  f"sys.exit(run('cut:main', 'cut', quiet={quiet}))", tmp_path)
    _, err = proc.communicate(timeout=30)
    assert (proc.returncode, err) == (status, said)
    proc = python('import sys; from tt_ros.entry import run; '
                  f"sys.exit(run('broken:main', 'broken', quiet={quiet}))", tmp_path)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 1 and 'ImportError: no module named nothing' in err


def test_the_function_s_result_is_the_exit_status(tmp_path):
    (tmp_path / 'quick.py').write_text('def main():\n    return 7\n')
    proc = python("import sys; from tt_ros.entry import run; sys.exit(run('quick:main', 'q'))",
                  tmp_path)
    out, err = proc.communicate(timeout=30)
    assert (proc.returncode, out, err) == (7, '', '')


@pytest.mark.parametrize('package_dir, exe, target', NODE_AND_CLI_SCRIPTS,
                         ids=[s[1] for s in NODE_AND_CLI_SCRIPTS])
def test_console_script_runs_its_main_through_run(package_dir, exe, target):
    module, _, function = target.partition(':')
    assert module == f'{package_dir.name}.entry', f'{exe} does not start through entry.run'
    entry = package_dir / package_dir.name / 'entry.py'
    body = {f.name: f for f in ast.parse(entry.read_text()).body
            if isinstance(f, ast.FunctionDef)}[function]
    call = body.body[-1].value
    assert isinstance(call, ast.Call) and call.func.id == 'run'
    real, name = (ast.literal_eval(a) for a in call.args)
    assert name == exe, 'the interrupted line must name the executable the user typed'
    real_module, _, real_function = real.partition(':')
    node = {k.arg: ast.literal_eval(k.value) for k in call.keywords}.get('quiet', False)
    assert node == (real_module.endswith('.node') or exe in QUIET_COMMANDS), (
        'a node stops cleanly, a command says so')

    path = SRC / package_dir.name / (real_module.replace('.', '/') + '.py')
    defined = {f.name for f in ast.parse(path.read_text()).body
               if isinstance(f, ast.FunctionDef)}
    assert real_function in defined, f'{real} does not exist'


def test_entry_modules_import_nothing_heavy(tmp_path):
    modules = sorted({t.partition(':')[0] for _, _, t in NODE_AND_CLI_SCRIPTS})
    code = (f'import sys; import {", ".join(modules)}; '
            f'print(sorted(m for m in {HEAVY!r} if m in sys.modules))')
    out, err = python(code, tmp_path).communicate(timeout=60)
    assert out.strip() == '[]', err


def _writer(tmp_path, body, stdout):
    """A process whose console-script body is ``body`` (Python source of ``main``), stdout
    to ``stdout``: (status, stderr)."""
    (tmp_path / 'writer.py').write_text(body)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path)] + sys.path))
    env.pop('PYTHONUNBUFFERED', None)         # stdout block-buffered, as a file's or a pipe's
    proc = subprocess.run(
        [sys.executable, '-c', "import sys; from tt_ros.entry import run; "
                               "sys.exit(run('writer:main', 'writer'))"],
        env=env, stdout=stdout, stderr=subprocess.PIPE, text=True, timeout=60)
    return proc.returncode, proc.stderr


SMALL = 'def main():\n    print("a line")\n    return 0\n'
LARGE = 'def main():\n    print("x" * 100000)\n    return 0\n'
FAILED = """\
import sys
def main():
    try:
        print('a line', flush=True)
    except OSError as exc:
        print(f'writer: {exc.strerror}', file=sys.stderr)
        return 2
    return 0
"""


@pytest.mark.skipif(not os.path.exists('/dev/full'), reason='needs /dev/full')
@pytest.mark.parametrize('body', [SMALL, LARGE], ids=['buffered till exit', 'written at once'])
def test_output_to_a_full_disk_is_one_line_and_status_1(tmp_path, body):
    with open('/dev/full', 'w') as full:
        assert _writer(tmp_path, body, full) == (
            1, 'writer: cannot write the output: No space left on device\n')


@pytest.mark.skipif(not os.path.exists('/dev/full'), reason='needs /dev/full')
def test_a_failure_already_reported_keeps_its_status_and_line(tmp_path):
    with open('/dev/full', 'w') as full:
        assert _writer(tmp_path, FAILED, full) == (2, 'writer: No space left on device\n')


def test_a_reader_that_went_away_ends_it_quietly(tmp_path):
    read, write = os.pipe()
    os.close(read)                          # as `| head` once it has its lines
    with os.fdopen(write, 'w') as pipe:
        assert _writer(tmp_path, LARGE, pipe) == (0, '')
