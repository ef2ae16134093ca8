"""ros2 run: ament-index lookup, error paths, exec with arguments; handover to a real ros2cli."""

import os
import pathlib
import shutil
import subprocess
import sys
import time

from conftest import ROS2, ros2
import pytest
from tt_tools.procs import ros_env
from tt_tools.run import RunError, executables, find_executable, package_prefix


def _fake_prefix(root, package, exes):
    marker = root / 'share' / 'ament_index' / 'resource_index' / 'packages' / package
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.write_text('')
    lib = root / 'lib' / package
    lib.mkdir(parents=True, exist_ok=True)
    for name, mode in exes.items():
        (lib / name).write_text('#!/bin/sh\necho "$0 $@"\n')
        (lib / name).chmod(mode)
    return root


def test_lookup_follows_the_ament_prefix_path_in_order(tmp_path):
    first = _fake_prefix(tmp_path / 'a', 'demo_pkg', {'talker': 0o755, 'notes.txt': 0o644})
    second = _fake_prefix(tmp_path / 'b', 'demo_pkg', {'listener': 0o755})
    search = os.pathsep.join([str(tmp_path / 'empty'), str(first), str(second)])
    assert package_prefix('demo_pkg', search) == str(first)
    assert executables('demo_pkg', search) == ['talker']  # not the non-executable file
    assert find_executable('demo_pkg', 'talker', search) == str(first / 'lib/demo_pkg/talker')
    with pytest.raises(RunError, match="No executable 'listener'"):
        find_executable('demo_pkg', 'listener', search)
    with pytest.raises(RunError, match="Package 'other' not found"):
        find_executable('other', 'talker', search)


@pytest.mark.parametrize('args, words', [
    (('no_such_package', 'node'), "Package 'no_such_package' not found"),
    (('tt_tools', 'no_such_executable'), "No executable 'no_such_executable'"),
    (('--prefix', 'no_such_command -x', 'tt_tools', 'bringup'),
     "--prefix 'no_such_command -x': no command 'no_such_command' on PATH"),
    (('--prefix', '"unclosed', 'tt_tools', 'bringup'), 'No closing quotation'),
])
def test_unknown_package_or_executable_is_one_line_and_exit_1(args, words):
    rc, out, err = ros2('run', *args)
    assert rc == 1 and out == ''
    assert err.count('\n') == 1 and words in err


def test_an_argument_too_many_is_reported_with_the_subcommand_usage():
    rc, out, err = ros2('param', 'get', '/some_node', 'stale_after_s', 'hit_plane_x')
    assert rc == 2 and out == ''
    lines = err.strip().splitlines()
    assert lines[0].startswith('usage: ros2 param get ')
    assert lines[-1] == 'ros2 param get: error: unrecognized arguments: hit_plane_x'


def test_an_invalid_topic_name_is_one_line_without_rcl_source_location():
    rc, out, err = ros2('topic', 'echo', 'bad topic!')
    assert rc == 1 and out == ''
    assert err.startswith("ros2 topic: topic name '/bad topic!' is invalid: ")
    assert err.count('\n') == 1 and '.c:' not in err


@pytest.mark.parametrize('argv, line', [
    # These were tracebacks (rclpy's InvalidTopicNameException, InvalidServiceNameException).
    (['topic', 'pub', '/ball/state/', 'tt_msgs/msg/BallState', '{}', '--once', '-w', '0'],
     "ros2 topic: Invalid topic name: topic name must not end with a forward slash: "
     "'/ball/state/'"),
    (['param', 'list', 'bad node'],
     "ros2 param: node name 'bad node' is invalid: a name must not contain characters other "
     "than alphanumerics, '_', or '/'"),
    (['param', 'get', '/x//y', 'foo'],
     "ros2 param: node name '/x//y' is invalid: a name must not contain repeated '/'"),
])
def test_an_invalid_node_or_topic_name_is_one_line(argv, line):
    rc, out, err = ros2(*argv)
    assert (rc, out, err) == (1, '', line + '\n')


def test_run_without_an_executable_names_only_what_is_missing():
    # It said 'required: executable, argv', though nothing need follow the executable.
    rc, out, err = ros2('run', 'tt_prediction')
    assert (rc, out) == (2, '')
    assert err.strip().splitlines()[-1] == ('ros2 run: error: the following arguments are '
                                            'required: executable')


@pytest.mark.parametrize('argv', [['bag', 'record', '--qos-depth', '-2', '/x'],
                                  ['bag', 'play', '--qos-depth', '0', 'bag'],
                                  ['topic', 'echo', '--qos-depth', '0', '/x']])
def test_a_queue_depth_below_one_is_a_usage_error(argv):
    # -2 was taken by bag record (rclpy then raised, or kept nothing).
    rc, out, err = ros2(*argv)
    assert (rc, out) == (2, '')
    assert err.strip().splitlines()[-1].endswith(
        f'argument --qos-depth: {argv[3]} is not an integer >= 1')


def test_run_execs_the_installed_executable_with_its_arguments(tmp_path):
    prefix = _fake_prefix(tmp_path, 'demo_pkg', {'talker': 0o755})
    env = {'AMENT_PREFIX_PATH': str(prefix)}
    rc, out, err = ros2('run', 'demo_pkg', 'talker', 'x', '--ros-args', '-p', 'a:=1', env=env)
    assert rc == 0, err
    assert out == f'{prefix}/lib/demo_pkg/talker x --ros-args -p a:=1\n'


def test_hands_over_to_a_real_ros2cli_when_importable(tmp_path):
    fake = tmp_path / 'ros2cli'
    fake.mkdir()
    (fake / '__init__.py').write_text('')
    (fake / 'cli.py').write_text('import sys\n\ndef main():\n'
                                 '    print("real ros2cli", sys.argv[1:])\n    return 3\n')
    env = ros_env({'PYTHONPATH': f'{tmp_path}{os.pathsep}{os.environ.get("PYTHONPATH", "")}'})
    env.pop('TT_ROS2_NO_HANDOVER', None)
    out = subprocess.run([*ROS2, 'topic', 'list'], env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 3 and out.stdout == "real ros2cli ['topic', 'list']\n"
    env['TT_ROS2_NO_HANDOVER'] = '1'
    out = subprocess.run([*ROS2, 'run', 'no_such_package', 'x'], env=env, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 1 and 'not found' in out.stderr


def test_ros2_on_path_is_the_workspace_script():
    found = shutil.which('ros2')
    if found is None:
        pytest.skip('env.sh not sourced: no ros2 on PATH')
    top = pathlib.Path(__file__).resolve().parents[3]
    assert pathlib.Path(found).resolve().is_relative_to(top / 'install' / 'tt_tools'), found


def test_native_writes_to_fd_1_go_to_stderr_and_python_output_stays_on_stdout():
    # What the DDS library prints (Fast DDS logs errors on fd 1) must not mix with echo's YAML.
    code = ('import os, sys\nfrom tt_tools.ros2 import _keep_stdout_for_output\n'
            '_keep_stdout_for_output()\nos.write(1, b"native log\\n")\nprint("a: 1")\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0
    assert out.stdout == 'a: 1\n' and out.stderr == 'native log\n'


@pytest.mark.parametrize('plane', ['5', '-3.5', 'nan', '-3'])
def test_demo_refuses_a_hit_plane_its_balls_cannot_reach_before_writing(tmp_path, capsys,
                                                                        plane):
    # Outside the prediction node's range [-3, 0] m, or in it but where none of the demo's
    # balls arrive (-3 m): one error line and exit 2, as for --target-zone, and no
    # recording.partial (or anything else) left behind.
    from tt_tools import demo
    out = tmp_path / 'demo'
    with pytest.raises(SystemExit) as exit_:
        demo.main(['--out', str(out), '--hit-plane-x', plane])
    assert exit_.value.code == 2
    said = capsys.readouterr()
    errors = [line for line in said.err.splitlines() if 'error:' in line]
    assert said.out == '' and 'Traceback' not in said.err
    assert len(errors) == 1 and '--hit-plane-x' in errors[0]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize('option, value', [('--balls', '0'), ('--rate', '0'), ('--rate', 'nan')])
def test_demo_names_the_one_bad_option(tmp_path, capsys, option, value):
    # '--balls must be >= 1 and --rate > 0' named both for one bad value (a walk-through).
    from tt_tools import demo
    with pytest.raises(SystemExit) as exit_:
        demo.main(['--out', str(tmp_path / 'demo'), option, value])
    assert exit_.value.code == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if 'error:' in line]
    assert len(errors) == 1 and option in errors[0] and f'got {value}' in errors[0]
    other = {'--balls': '--rate', '--rate': '--balls'}[option]
    assert other not in errors[0]
    assert list(tmp_path.iterdir()) == []


def test_demo_refuses_an_out_that_is_a_file_before_writing(tmp_path, capsys):
    # --out is a folder: an existing file is one error line and exit 2 (it was a
    # FileExistsError traceback once the recording was made), the file untouched.
    from tt_tools import demo
    out = tmp_path / 'demo.jsonl'
    out.write_text('keep')
    with pytest.raises(SystemExit) as exit_:
        demo.main(['--out', str(out)])
    assert exit_.value.code == 2
    said = capsys.readouterr()
    errors = [line for line in said.err.splitlines() if 'error:' in line]
    assert said.out == '' and 'Traceback' not in said.err
    assert len(errors) == 1 and '--out' in errors[0] and 'not a folder' in errors[0]
    assert out.read_text() == 'keep' and list(tmp_path.iterdir()) == [out]


@pytest.mark.parametrize('ending', ['os._exit(0)', 'os.kill(os.getpid(), signal.SIGKILL)'])
def test_a_process_group_does_not_outlive_its_parent(tmp_path, ending):
    """The demo ended by `timeout` (SIGTERM) or a closed terminal left its four nodes
    running for ever: what a ProcessGroup starts gets SIGTERM when its parent ends, however
    it ends, with no cleanup of its own (a walk-through, 6 Dec 2026)."""
    script = (
        'import os, signal, sys\n'
        'from tt_tools.procs import ProcessGroup\n'
        f'group = ProcessGroup({str(tmp_path)!r})\n'
        "child = group.start('sleeper', [sys.executable, '-c', 'import time; time.sleep(60)'])\n"
        'print(child.pid, flush=True)\n'
        f'{ending}\n')
    parent = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                            env=ros_env(), timeout=60)
    pid = int(parent.stdout.split()[0])
    # The child is no child of this process: poll /proc until it is gone or a zombie.
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        try:
            state = pathlib.Path(f'/proc/{pid}/stat').read_text().split()[2]
        except FileNotFoundError:
            break
        if state == 'Z':
            break
        time.sleep(0.05)
    else:
        os.kill(pid, 9)
        raise AssertionError(f'the child {pid} outlived its parent')
