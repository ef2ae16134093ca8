"""The workspace set-up: CMake path rewrite, env file, message definitions."""

import os
import pathlib
import subprocess
import sys
import sysconfig
import xml.etree.ElementTree as ET

import numpy
import pytest

TOP = pathlib.Path(__file__).resolve().parents[1]

STALE = ('INTERFACE_INCLUDE_DIRECTORIES "/opt/python/cp312-cp312/include/python3.12;'
         '/opt/python/cp312-cp312/lib/python3.12/site-packages/numpy/_core/include"\n')


def _patch(venv):
    return subprocess.run([sys.executable, str(TOP / 'scripts' / 'patch_cmake_paths.py'),
                           str(venv)], capture_output=True, text=True, check=True)


def test_cmake_paths_point_at_this_interpreter_and_rewrite_is_idempotent(tmp_path):
    target = tmp_path / 'share' / 'std_msgs' / 'cmake' / 'export.cmake'
    target.parent.mkdir(parents=True)
    target.write_text(STALE)
    untouched = tmp_path / 'share' / 'other.cmake'
    untouched.write_text('set(X 1)\n')

    first = _patch(tmp_path)
    text = target.read_text()
    assert '/opt/python' not in text
    assert sysconfig.get_paths()['include'] in text
    assert numpy.get_include() in text
    assert 'rewrote stale include paths in 1 ' in first.stderr

    second = _patch(tmp_path)
    assert target.read_text() == text
    assert 'in 0 ' in second.stderr
    assert untouched.read_text() == 'set(X 1)\n'


def test_another_venvs_paths_are_rewritten_without_touching_a_hard_linked_original(tmp_path):
    # uv links the wheels' files from its cache: a path patched for one venv must not leak
    # into the cache (and from there into the next venv).
    other = ('INTERFACE_INCLUDE_DIRECTORIES "/tmp/old/.pyenv/include/python3.12;'
             '/tmp/old/.venv/lib/python3.12/site-packages/numpy/_core/include"\n')
    cached = tmp_path / 'cache.cmake'
    cached.write_text(other)
    target = tmp_path / 'venv' / 'share' / 'std_msgs' / 'cmake' / 'export.cmake'
    target.parent.mkdir(parents=True)
    os.link(cached, target)

    _patch(tmp_path / 'venv')
    text = target.read_text()
    assert '/tmp/old' not in text
    assert f'"{sysconfig.get_paths()["include"]};{numpy.get_include()}"' in text
    assert cached.read_text() == other


def test_installed_wheels_have_no_stale_include_paths():
    share = pathlib.Path(sys.prefix, 'share')
    stale = [p for p in share.rglob('*.cmake') if '/opt/python/' in p.read_text()]
    assert stale == []


def test_env_file_keeps_discovery_on_this_machine():
    env = (TOP / 'env.sh').read_text()
    assert 'ROS_AUTOMATIC_DISCOVERY_RANGE' in env
    out = subprocess.run(['bash', '-c', f'set +u; env -u ROS_AUTOMATIC_DISCOVERY_RANGE bash -c '
                          f'". {TOP}/env.sh; echo $ROS_AUTOMATIC_DISCOVERY_RANGE"'],
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == 'LOCALHOST'


SEARCH_PATHS = ('PATH', 'LD_LIBRARY_PATH', 'PYTHONPATH', 'AMENT_PREFIX_PATH', 'CMAKE_PREFIX_PATH',
                'COLCON_PREFIX_PATH', 'FASTRTPS_DEFAULT_PROFILES_FILE')


def _sourced(env, times=1):
    """The search paths (name -> list of entries) and TT_WORKSPACE after sourcing env.sh."""
    script = ('set +u; ' + f'. {TOP}/env.sh; ' * times
              + 'for v in TT_WORKSPACE ' + ' '.join(SEARCH_PATHS) + '; do echo "$v=${!v}"; done')
    out = subprocess.run(['bash', '-c', script], env=env, capture_output=True, text=True,
                         check=True).stdout
    values = dict(line.split('=', 1) for line in out.splitlines())
    return values.pop('TT_WORKSPACE'), {k: v.split(':') if v else [] for k, v in values.items()}


def test_env_file_leaves_another_tt_workspace_sourced_before():
    # A Python 3.11 clone built and tested from a shell where /work/main's env.sh (3.12) was
    # sourced: its builds chained /work/main's install, and its processes loaded /work/main's
    # tt_msgs library in half of the runs (ros_wheels_bootstrapper shuffles LD_LIBRARY_PATH);
    # the first message published aborted (6 Dec 2026).
    other = '/tmp/another-tt'
    env = {**os.environ, 'TT_WORKSPACE': other,
           'LD_LIBRARY_PATH': f'{other}/install/tt_msgs/lib:/opt/kept/lib',
           'PYTHONPATH': f'{other}/install/tt_ros/lib/python3.12/site-packages',
           'COLCON_PREFIX_PATH': other + '/install',
           'AMENT_PREFIX_PATH': f'{other}/.venv:{other}/install/tt_msgs',
           'CMAKE_PREFIX_PATH': other,
           'FASTRTPS_DEFAULT_PROFILES_FILE': f'{other}/install/tt_tools/share/tt_tools/config/'
                                             'fastdds_large_messages.xml',
           'PATH': f'{other}/.venv/bin:{other}-not-it/bin:' + os.environ['PATH']}
    workspace, paths = _sourced(env)
    assert os.path.realpath(workspace) == str(TOP)     # env.sh's path is pwd's, TOP real
    for name, entries in paths.items():
        assert not [e for e in entries if e == other or e.startswith(other + '/')], name
    assert '/opt/kept/lib' in paths['LD_LIBRARY_PATH']
    assert f'{other}-not-it/bin' in paths['PATH']
    assert f'{TOP}/.venv/bin' in paths['PATH']
    # Its own workspace's paths stay when it is sourced again.
    workspace, again = _sourced(env, times=2)
    assert f'{TOP}/.venv' in again['AMENT_PREFIX_PATH'] and f'{TOP}/.venv/bin' in again['PATH']


@pytest.mark.parametrize('name, fields', [
    ('BallState', {'header', 'position', 'velocity', 'spin', 'covariance', 'track_id'}),
    ('BallPrediction', {'status', 'bounce_point', 'bounce_zone', 'bounce_half', 'hit_point',
                        'hit_velocity', 'hit_spin', 'zone_probabilities'}),
    ('StrikeCommand', {'hit_time', 'racket_position', 'racket_orientation', 'racket_normal',
                       'racket_velocity', 'ball_out_velocity', 'landing_point', 'landing_zone',
                       'feasible', 'margin'}),
])
def test_messages_carry_the_fields_of_the_design(name, fields):
    msgs = pytest.importorskip('tt_msgs.msg')
    cls = getattr(msgs, name)
    assert fields <= set(cls.get_fields_and_field_types())


def test_every_field_of_every_message_is_documented():
    for path in sorted((TOP / 'src' / 'tt_msgs' / 'msg').glob('*.msg')):
        lines = path.read_text().splitlines()
        for i, line in enumerate(lines):
            if not line.strip() or line.lstrip().startswith('#'):
                continue
            documented = '#' in line or (i > 0 and lines[i - 1].lstrip().startswith('#'))
            assert documented, f'{path.name}: field without a comment: {line!r}'


def test_ball_state_covariance_is_9x9():
    msgs = pytest.importorskip('tt_msgs.msg')
    assert msgs.BallState.get_fields_and_field_types()['covariance'] == 'double[81]'
    assert os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') == 'LOCALHOST'


@pytest.mark.parametrize('command, package', [
    (['tt-predict'], 'tt_prediction'), (['tt-predict', '--tracks', 'x'], 'tt_prediction'),
    (['tt-identify'], 'tt_prediction'), (['tt-strike'], 'tt_strike'),
    (['tt-perceive'], 'tt_perception')])
def test_each_command_names_its_version_from_package_xml(command, package):
    # `--version` was an unrecognised argument (exit 2) in every command.
    xml = ET.parse(TOP / 'src' / package / 'package.xml').getroot()
    proc = subprocess.run([*command, '--version'], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == f'{command[0]} {xml.findtext("version")}\n'
