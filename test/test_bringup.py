"""`ros2 run tt_tools bringup` (issue 17 item 1): the graph from one parameters file, a node
that dies restarted with one line, SIGINT stops every node cleanly (exit 0, no rosout noise),
a node that does not stop writes its stacks before its SIGKILL, no node outlives a killed
bringup, bad input is one line and exit 2; on a rig of video files with the shipped
replay.yaml it prints a prediction and a strike command for every ball.

Each test runs in a ROS domain of its own and waits on output lines (conditions), never on
sleeps.
"""

import os
import pathlib
import re
import signal
import subprocess
import threading
import time

import pytest
from tt_ros.testing import unique_domain
from tt_tools.procs import ros_env

pytestmark = pytest.mark.graph

TIMEOUT_S = 180.0
CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'src' / 'tt_tools' / 'config'


class Bringup:
    """A bringup process whose output lines are collected by a thread."""

    def __init__(self, *args):
        self.domain = unique_domain()
        env = ros_env({'ROS_DOMAIN_ID': str(self.domain)})
        self.proc = subprocess.Popen(['ros2', 'run', 'tt_tools', 'bringup', *args], env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, text=True,
                                     start_new_session=True)
        self.lines = []
        self.changed = threading.Condition()
        self.thread = threading.Thread(target=self._pump, daemon=True)
        self.thread.start()

    def _pump(self):
        for line in self.proc.stdout:
            with self.changed:
                self.lines.append(line.rstrip('\n'))
                self.changed.notify_all()
        with self.changed:
            self.changed.notify_all()

    def wait_for(self, pattern, count=1):
        """The ``count``-th line matching ``pattern``; TimeoutError naming it."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + TIMEOUT_S
        with self.changed:
            while True:
                found = [m for m in map(regex.search, self.lines) if m]
                if len(found) >= count:
                    return found[count - 1]
                if self.proc.poll() is not None and not self.thread.is_alive():
                    raise AssertionError(f'bringup ended before {pattern!r}:\n' + self.text)
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f'no line {pattern!r} in {TIMEOUT_S} s:\n' + self.text)
                self.changed.wait(left)

    @property
    def text(self):
        return '\n'.join(self.lines)

    def stop(self, sig=signal.SIGINT):
        """Signal bringup (only bringup: the nodes are in sessions of their own); exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(TIMEOUT_S)
        finally:
            self.thread.join(10)

    def kill(self):
        """End a bringup that a failed test left running: SIGINT first, so that the nodes'
        last lines (and the stacks of one that does not stop) come out, then the whole output
        printed for pytest's report of the failure; SIGKILL if it is still there."""
        if self.proc.poll() is None:
            try:
                self.stop()
            except subprocess.TimeoutExpired:
                pass
            print(self.text)
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()


def _params(tmp_path, text):
    path = tmp_path / 'graph.yaml'
    path.write_text(text)
    return str(path)


GRAPH = """
prediction_node:
  ros__parameters:
    uncertainty: false
strike_node:
  ros__parameters:
    target_zone: 3
"""


def _locked_by(pid):
    """The files in /dev/shm that process ``pid`` holds a lock on (flock, as Fast DDS locks
    the files of its participant's shared memory), from the kernel's /proc/locks."""
    inodes = set()
    with open('/proc/locks') as locks:
        for line in locks:
            f = line.split()      # '1: FLOCK  ADVISORY  WRITE <pid> <maj>:<min>:<inode> 0 EOF'
            if f[1] == 'FLOCK' and f[4] == str(pid):
                inodes.add(int(f[5].split(':')[2]))
    names = []
    for name in os.listdir('/dev/shm'):
        try:
            if os.stat(os.path.join('/dev/shm', name)).st_ino in inodes:
                names.append(name)
        except OSError:
            pass
    return names


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_killed_node_is_restarted_with_one_line_and_a_signal_stops_all(tmp_path, sig):
    run = Bringup('--params-file', _params(tmp_path, GRAPH), '--restart-delay', '0.2')
    try:
        run.wait_for(r'^\[strike_node\] .*\]: ready$')
        pid = int(run.wait_for(r'^bringup: started prediction_node \(pid (\d+)\)').group(1))
        run.wait_for(r'^\[prediction_node\] .*\]: ready$')
        # Its participant's data segments (the lock files it holds; its ports stay).
        own = [name for name in _locked_by(pid) if not name.startswith('fastrtps_port')]
        os.kill(pid, signal.SIGKILL)
        removed = run.wait_for(r'^bringup: prediction_node ended: removed (\d+) Fast DDS '
                               r'shared-memory files in /dev/shm that no running process '
                               r'holds$')
        died = run.wait_for(r'^bringup: prediction_node died .*$').group(0)
        assert re.fullmatch(r'bringup: prediction_node died \(signal SIGKILL\) after '
                            r'[\d.]+ s; restart 1', died), died
        # A killed participant leaves its segments; bringup removed them (each lock file
        # with the segment it guards).
        assert own and int(removed.group(1)) >= 2 * len(own), (own, removed.group(0))
        assert not [name for name in own if os.path.exists(os.path.join('/dev/shm', name))]
        new_pid = int(run.wait_for(r'^bringup: started prediction_node \(pid (\d+)\)',
                                   count=2).group(1))
        assert new_pid != pid
        run.wait_for(r'^\[prediction_node\] .*\]: ready$', count=2)
        code = run.stop(sig)
    finally:
        run.kill()
    assert code == 0, run.text
    assert run.lines[-1] == 'bringup: stopped'
    # Each node logged its last lines while its context was valid: no rosout noise, no
    # traceback, and prediction_node's summary came out.
    assert 'rosout' not in run.text and 'Traceback' not in run.text
    assert re.search(r'\[prediction_node\] .*: no state received', run.text)
    assert len([ln for ln in run.lines if 'died' in ln]) == 1


def _gone(pid, timeout):
    """Whether process ``pid`` (not a child of ours) ends within ``timeout`` s: a pidfd
    becomes readable when it does."""
    import select
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    try:
        return bool(select.select([fd], [], [], timeout)[0])
    finally:
        os.close(fd)


def test_the_nodes_end_with_bringup_even_when_it_is_killed(tmp_path):
    run = Bringup('--params-file', _params(tmp_path, GRAPH))
    pids = []
    try:
        run.wait_for(r'^\[prediction_node\] .*\]: ready$')
        pids = [int(run.wait_for(rf'^bringup: started {name} \(pid (\d+)\)').group(1))
                for name in ('strike_node', 'prediction_node')]
        os.kill(run.proc.pid, signal.SIGKILL)     # no handler runs: only the kernel's signal
        run.proc.wait()
        left = [pid for pid in pids if not _gone(pid, 20.0)]
        seen = {pid: _process_state(pid) for pid in left}
    finally:
        run.kill()
        for pid in pids:
            if not _gone(pid, 0.0):
                os.kill(pid, signal.SIGKILL)
    assert left == [], f'{seen}\n{run.text}'


def _process_state(pid):
    """What the kernel says of a process that did not end (for a failure's message): its
    state and signal masks (was the parent's SIGTERM pending, blocked, ignored, caught?)
    and where each of its threads waits."""
    proc = pathlib.Path(f'/proc/{pid}')
    try:
        status = [line for line in (proc / 'status').read_text().splitlines()
                  if line.split(':')[0] in ('Name', 'State', 'PPid', 'SigPnd', 'ShdPnd',
                                            'SigBlk', 'SigIgn', 'SigCgt')]
        waits = sorted({(task / 'wchan').read_text() for task in (proc / 'task').iterdir()})
    except OSError as exc:
        return f'gone or unreadable: {exc}'
    return '; '.join(status) + '; threads wait in ' + ', '.join(waits)


# A node run by tt_ros.executor.run_node that does not stop: it says it is ready, then its
# start-up never returns (as a kernel stuck in compiled code would not); SIGINT and SIGTERM
# only set the flag of a spin loop it never reaches.
STUCK_NODE = """
import time
from tt_ros import executor
def stuck_in_start_up():
    print('[INFO] [0.0] [prediction_node]: ready', flush=True)
    time.sleep(600)
executor.run_node(stuck_in_start_up)
"""


def test_a_node_that_does_not_stop_writes_its_stacks_before_its_sigkill(tmp_path, capsys):
    import sys

    from tt_tools.bringup import Bringup as Supervisor

    supervisor = Supervisor(_params(tmp_path, GRAPH), ['prediction_node'], stop_timeout=0.5,
                            env=ros_env({'ROS_DOMAIN_ID': str(unique_domain())}))
    supervisor.children[0].argv = [sys.executable, '-c', STUCK_NODE]
    ready = threading.Event()
    put = supervisor.events.put

    def put_and_tell(event):
        if event[0] == 'ready':
            ready.set()
        put(event)

    supervisor.events.put = put_and_tell
    status = []
    thread = threading.Thread(target=lambda: status.append(supervisor.run()))
    thread.start()
    try:
        assert ready.wait(TIMEOUT_S)
    finally:
        supervisor.request_stop()
        thread.join(TIMEOUT_S)
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert status == [1], out
    said = lines.index('bringup: prediction_node did not stop on SIGINT nor SIGTERM; the '
                       'stacks of its threads follow, then SIGKILL')
    assert any('in stuck_in_start_up' in ln for ln in lines[said:]), out
    assert lines[-1] == 'bringup: stopped; not clean: prediction_node SIGKILL', out


def test_a_node_that_cannot_start_stops_the_graph_with_exit_2(tmp_path):
    graph = GRAPH.replace('target_zone: 3', 'target_zone: 12')
    run = Bringup('--params-file', _params(tmp_path, graph))
    try:
        code = run.proc.wait(TIMEOUT_S)
    finally:
        run.kill()
        run.thread.join(10)
    assert code == 2, run.text
    assert '[strike_node] strike_node: target_zone: 12 is not an integer in [0, 9]' in run.lines
    assert any(re.fullmatch(r'bringup: strike_node cannot start \(exit 2\): .*target_zone.*'
                            r'; stopping the graph', ln) for ln in run.lines), run.text
    assert 'restart' not in run.text and 'Traceback' not in run.text


@pytest.mark.parametrize('text, words', [
    (None, 'No such file'),
    ('prediction_node: [1, 2\n', 'not valid YAML (line'),
    ('other_node:\n  ros__parameters: {}\n', 'names none of the tt nodes'),
    ('prediction_node:\n  use_sim_time: true\n', 'prediction_node: no ros__parameters'),
    # A video given for it: a traceback (UnicodeDecodeError; a walk-through, 6 Dec 2026).
    (b'RIFF\x9c\xff\x00AVI LIST', 'not valid YAML (not UTF-8 text)'),
])
def test_bad_parameters_files_are_one_line_and_exit_2(tmp_path, text, words):
    if isinstance(text, bytes):
        path = str(tmp_path / 'cam0.avi')
        pathlib.Path(path).write_bytes(text)
    else:
        path = str(tmp_path / 'missing.yaml') if text is None else _params(tmp_path, text)
    proc = subprocess.run(['ros2', 'run', 'tt_tools', 'bringup', '--params-file', path],
                          capture_output=True, text=True, env=ros_env(), timeout=TIMEOUT_S)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f'bringup: {path}: ') and words in lines[0]


def test_an_empty_nodes_list_is_refused_not_taken_as_all():
    proc = subprocess.run(['ros2', 'run', 'tt_tools', 'bringup', '--params-file',
                           str(CONFIG / 'replay.yaml'), '--nodes', ''],
                          capture_output=True, text=True, env=ros_env(), timeout=TIMEOUT_S)
    assert proc.returncode == 2
    assert proc.stderr.startswith('bringup: --nodes : not among the nodes of ')
    assert proc.stderr.count('\n') == 1


def test_each_output_line_is_written_in_one_piece(monkeypatch):
    # The children's pumps and bringup's own lines write from several threads: a line's
    # text and its newline written apart let another thread's line in between (a node's
    # 'ready' line and bringup's next one came out as one line, and a test missed 'ready').
    from tt_tools import bringup

    class Recorder:
        def __init__(self):
            self.writes = []

        def write(self, text):
            self.writes.append(text)

        def flush(self):
            pass

    out = Recorder()
    monkeypatch.setattr(bringup.sys, 'stdout', out)
    threads = [threading.Thread(target=lambda k=k: [bringup.say(f'line {k}.{i}')
                                                    for i in range(200)]) for k in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert len(out.writes) == 800
    assert all(w.startswith('bringup: line ') and w.endswith('\n') and w.count('\n') == 1
               for w in out.writes)


def test_restarts_are_counted_in_a_row_and_a_node_that_ran_a_while_starts_again(monkeypatch):
    # A robot's graph up for days: a node crashing once every few hours was restarted five
    # times and its sixth crash stopped the whole graph. The count is of quick deaths in a
    # row (each within STABLE_RUN_S of its start), as systemd's start limit is per window.
    from tt_tools import bringup
    lines = []
    monkeypatch.setattr(bringup, 'say', lines.append)
    monkeypatch.setattr(bringup, 'remove_dead_segments', lambda: [])
    graph = bringup.Bringup.__new__(bringup.Bringup)
    graph.max_restarts, graph.restart_delay, graph.stopping, graph.status = 2, 1.0, False, 0
    graph.pending = {}
    child = bringup.Child('prediction_node', [], {}, None)

    def dies_after(seconds):
        proc = subprocess.CompletedProcess([], -9)
        child.proc, child.started = proc, time.monotonic() - seconds
        graph._exited(child, proc)

    for _ in range(10):             # hours apart: none counted
        dies_after(bringup.STABLE_RUN_S + 1.0)
        assert not graph.stopping and lines[-1].endswith('not counted)')
    for n in (1, 2):                # quick deaths in a row, up to --max-restarts
        dies_after(1.0)
        assert not graph.stopping and lines[-1].endswith(f'restart {n}')
    dies_after(1.0)                 # the third: more than 2
    assert graph.stopping and graph.status == 1
    assert 'more than 2 restarts in a row' in lines[-1]
    # --max-restarts 0: a node that ran an hour is restarted; a quick death stops the graph.
    graph.max_restarts, graph.stopping, graph.status, child.restarts = 0, False, 0, 0
    dies_after(3600.0)
    assert not graph.stopping and lines[-1].endswith('not counted)')
    dies_after(1.0)
    assert graph.stopping and 'more than 0 restarts in a row' in lines[-1]

@pytest.mark.parametrize('option, value, meaning', [
    ('--restart-delay', 'nan', 'a number >= 0'), ('--restart-delay', '-5', 'a number >= 0'),
    ('--stop-timeout', 'nan', 'a number > 0'), ('--stop-timeout', '0', 'a number > 0'),
    ('--max-restarts', '-1', 'an integer >= 0')])
def test_a_time_or_count_outside_its_meaning_is_a_usage_error(option, value, meaning):
    # A nan restart delay was taken, and a node that died was then never started again.
    proc = subprocess.run(['ros2', 'run', 'tt_tools', 'bringup', '--params-file',
                           str(CONFIG / 'replay.yaml'), option, value],
                          capture_output=True, text=True, env=ros_env(), timeout=TIMEOUT_S)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].endswith(
        f'argument {option}: {value} is not {meaning}')


@pytest.mark.parametrize('missing, words', [(True, 'no such file'), (False, 'not a file')])
def test_a_rig_that_is_no_file_is_one_line_and_exit_2(tmp_path, missing, words):
    rig = tmp_path / 'rig.yaml' if missing else tmp_path
    proc = subprocess.run(['ros2', 'run', 'tt_tools', 'bringup', '--params-file',
                           str(CONFIG / 'replay.yaml'), '--rig', str(rig)],
                          capture_output=True, text=True, env=ros_env(), timeout=TIMEOUT_S)
    assert proc.returncode == 2
    assert proc.stderr == f'bringup: --rig {rig}: {words}\n'


def test_perception_without_a_rig_is_one_line_before_any_node_starts():
    # robot.yaml without --rig: prediction and strike came up, then the graph stopped with
    # perception_node's 'rig_file is empty' (a ROS user's walk-through).
    proc = subprocess.run(['ros2', 'run', 'tt_tools', 'bringup', '--params-file',
                           str(CONFIG / 'robot.yaml')],
                          capture_output=True, text=True, env=ros_env(), timeout=TIMEOUT_S)
    assert proc.returncode == 2
    assert proc.stderr == ('bringup: perception_node has no rig: give --rig RIG (or rig_file '
                           f'in a section of {CONFIG / "robot.yaml"} that applies to it)\n')
    assert proc.stdout == ''                                    # no node was started


def test_the_rig_a_params_file_gives_perception_is_its_last_sections(tmp_path):
    # rcl lets a later section override an earlier one: a /** rig followed by
    # perception_node's '' is no rig (bringup took the /** one, and perception failed later).
    from tt_tools.bringup import configured_rig, read_params
    path = tmp_path / 'params.yaml'
    path.write_text("/**:\n  ros__parameters:\n    rig_file: /some/rig.yaml\n"
                    "perception_node:\n  ros__parameters:\n    rig_file: ''\n")
    assert configured_rig(read_params(str(path))) == ''
    path.write_text('perception_node:\n  ros__parameters:\n    rig_file: /a.yaml\n'
                    '/**:\n  ros__parameters:\n    use_sim_time: true\n')
    assert configured_rig(read_params(str(path))) == '/a.yaml'


def test_shipped_configs_name_only_declared_parameters():
    from tt_perception.node import PARAMETERS as PERCEPTION
    from tt_prediction.node import PARAMETERS as PREDICTION
    from tt_strike.node import PARAMETERS as STRIKE
    import yaml

    declared = {'perception_node': PERCEPTION, 'prediction_node': PREDICTION,
                'strike_node': STRIKE}
    from tt_ros.parameters import coerce
    for name in ('robot.yaml', 'replay.yaml'):
        data = yaml.safe_load((CONFIG / name).read_text())
        assert set(data) == set(declared)
        for node, section in data.items():
            specs = {p.name: p for p in declared[node]}
            for key, value in section['ros__parameters'].items():
                if key == 'use_sim_time':
                    assert value is (name == 'replay.yaml')
                    continue
                assert key in specs, f'{name}: {node}.{key} is not a parameter'
                coerce(specs[key], value)           # raises for a refused value
    replay = yaml.safe_load((CONFIG / 'replay.yaml').read_text())
    assert replay['perception_node']['ros__parameters']['publish_clock'] is True


def test_show_waits_for_its_subscriptions_before_the_next_node_starts(monkeypatch):
    # --show's subscriptions are inputs like a node's: until each one has the running node
    # that publishes it, bringup does not start the next node (a video's first ball would
    # go by unshown); a topic whose publishing node does not run is not waited for.
    from tt_ros.testing import Graph

    from tt_msgs.msg import StrikeCommand
    from tt_tools import bringup

    domain = unique_domain()
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    show = bringup.Show()
    with Graph(domain_id=domain) as graph:
        supervisor = bringup.Bringup(str(CONFIG / 'robot.yaml'), ['strike_node'])
        supervisor.show = show
        strike = supervisor.children[0]
        strike.proc = object()                      # "running": only its name is looked at
        strike.connected = set()
        assert show.unconnected({'strike_node'}) == ['/strike/command']
        assert supervisor._unconnected() == ["--show's /strike/command"]
        assert show.unconnected({'perception_node'}) == []
        node = graph.create_node('strike_stand_in')
        node.create_publisher(StrikeCommand, '/strike/command', 10)
        graph.spin_until(lambda: not show.unconnected({'strike_node'}), 30.0,
                         "--show's /strike/command connected")
        assert supervisor._unconnected() == []
        assert show.unconnected({'strike_node', 'prediction_node'}) == ['/ball/prediction']
        show.close()


@pytest.mark.slow
def test_replay_config_on_a_rig_of_video_files_strikes_every_ball(tmp_path):
    from tt_perception.camera import load_rig

    from tt_perception import synth

    rig_path = synth.make_rig(str(tmp_path / 'calib'))
    balls = [synth.incoming_ball(), synth.incoming_ball(speed=7.0, topspin_rps=20.0)]
    frames, truth = synth.render_balls(load_rig(rig_path), balls, [0.0, 0.6], duration=1.2,
                                       lead_in=0.1)
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, truth,
                                  time_offset=0.0)   # synchronised: no offset to estimate
    run = Bringup('--params-file', str(CONFIG / 'replay.yaml'), '--rig', video_rig, '--show')
    try:
        end = run.wait_for(r'end of the video files: \d+ frames, (\d+) states')
        n_states = int(end.group(1))
        # A ball's line names its bounce when its first shown prediction came before it (on a
        # loaded machine the first one shown can come from after the bounce: no bounce left).
        shown = [run.wait_for(r'^bringup: ball \d+: (bounce zone \d .* )?hit .* strike (\w+)',
                              count=k + 1) for k in range(len(balls))]
        code = run.stop()
    finally:
        run.kill()
    assert code == 0, run.text
    assert [m.group(2) for m in shown] == ['ok'] * len(balls), run.text
    # The video's source started once strike_node's input was connected (DDS discovery
    # between prediction_node and strike_node can take seconds: the first ball was lost).
    lines = run.lines
    connected = [i for i, ln in enumerate(lines)
                 if re.fullmatch(r'\[strike_node\] .*\]: /ball/prediction: connected '
                                 r'\(\d+ publishers?\)', ln)]
    source = lines.index(next(ln for ln in lines if ln.startswith('bringup: started '
                                                                  'perception_node')))
    assert connected and connected[0] < source, run.text
    summary = re.search(r'\[prediction_node\] .*: (\d+) states, (\d+) predictions, (\d+) '
                        r'dropped', run.text)
    assert summary, run.text
    received, predicted, dropped = (int(v) for v in summary.groups())
    # Every state that reached prediction_node was predicted, none stale; the last few may
    # still be on their way when SIGINT comes (the strike lines do not wait for them).
    assert (predicted, dropped) == (received, 0) and received >= n_states - 3, run.text


@pytest.mark.parametrize('preset', ['', '/some/profile.xml'])
def test_env_sh_sets_the_large_image_profile_unless_one_is_set(preset):
    import shutil

    top = pathlib.Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if k != 'FASTRTPS_DEFAULT_PROFILES_FILE'}
    if preset:
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = preset
    script = 'set +u; . ./env.sh; echo "$FASTRTPS_DEFAULT_PROFILES_FILE"'
    out = subprocess.run(['bash', '-c', script], cwd=top, env=env, capture_output=True,
                         text=True, timeout=60)
    profile = out.stdout.strip().splitlines()[-1] if out.stdout.strip() else ''
    if preset:
        assert profile == preset
    elif shutil.disk_usage('/dev/shm').free >= 1 << 30:
        assert profile == str(top / 'install/tt_tools/share/tt_tools/config/'
                                    'fastdds_large_messages.xml')
    else:
        assert profile == ''


@pytest.mark.parametrize('namespace, sections, nodes', [
    # The sections the docs give for a node in any namespace: 'none of the tt nodes', and a
    # file with one plain and one such section started the plain one only (a walk-through).
    ('', ('/**/prediction_node', '/**/strike_node'), ['prediction_node', 'strike_node']),
    ('', ('prediction_node', '/**/strike_node'), ['prediction_node', 'strike_node']),
    ('/robot1', ('/robot1/prediction_node', 'strike_node'), ['prediction_node']),
    ('/robot1', ('/**',), ['perception_node', 'prediction_node', 'strike_node']),
    ('/robot1', ('/robot1/*',), ['perception_node', 'prediction_node', 'strike_node']),
    ('', ('/robot1/prediction_node',), None),
])
def test_a_files_sections_name_the_nodes_as_rcl_applies_them(namespace, sections, nodes):
    from tt_tools import bringup
    given = {key: {'rig_file': 'r.yaml'} for key in sections}
    if nodes is None:
        with pytest.raises(bringup.BringupError, match=r'names none of the tt nodes .*\(its '
                                                       r'sections: /robot1/prediction_node\)'):
            bringup.nodes_in(given, 'f.yaml', namespace)
        return
    assert bringup.nodes_in(given, 'f.yaml', namespace) == nodes
    assert bringup.configured_rig(given, namespace) == (
        'r.yaml' if 'perception_node' in nodes else '')


def test_a_graph_in_a_namespace_takes_the_states_of_its_own(tmp_path):
    """--namespace /robot1: every node in /robot1, --show on its topics; a state published on
    /robot1/ball/state is predicted and struck (bringup had no namespace: one robot a
    domain; a walk-through, 6 Dec 2026)."""
    from rclpy.qos import qos_profile_sensor_data
    from tt_ros.testing import Graph

    from tt_msgs.msg import BallState
    path = _params(tmp_path, GRAPH.replace('\nprediction_node:', '\n/**/prediction_node:')
                   .replace('\nstrike_node:', '\n/robot1/strike_node:'))
    b = Bringup('--params-file', path, '--nodes', 'prediction_node,strike_node',
                '--namespace', '/robot1', '--show')
    try:
        b.wait_for(r'^\[prediction_node\] .*\]: ready$')
        assert '-r __ns:=/robot1' not in b.text          # (said as the node names below)
        with Graph(domain_id=b.domain) as graph:
            node = graph.create_node('robot1_states')
            pub = node.create_publisher(BallState, '/robot1/ball/state', qos_profile_sensor_data)

            def shown():
                msg = BallState()
                now = node.get_clock().now().nanoseconds
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 1_000_000_000)
                msg.header.frame_id = 'table'
                msg.track_id = 1
                (msg.position.x, msg.position.y, msg.position.z) = (1.6, 0.1, 0.3)
                (msg.velocity.x, msg.velocity.y, msg.velocity.z) = (-6.0, 0.0, 1.5)
                msg.spin.y = 100.0
                pub.publish(msg)
                return any(line.startswith('bringup: ball 1: ') for line in b.lines)
            graph.spin_until(shown, TIMEOUT_S, "--show's line of the ball")
        assert re.search(r'\[strike_node\] .*/robot1/ball/prediction: connected', b.text)
        assert b.stop() == 0
    finally:
        b.kill()


def test_show_says_each_ball_once_and_a_ball_again_under_its_id(monkeypatch):
    # One line per ball: a bag played a second time, or a restarted perception_node numbering
    # from 1 again, showed nothing for an id already shown (a walk-through, 6 Dec 2026).
    from tt_msgs.msg import StrikeCommand
    from tt_tools import bringup
    said = []
    monkeypatch.setattr(bringup, 'say', said.append)
    show = bringup.Show.__new__(bringup.Show)
    show.shown, show.last_prediction = {}, {}

    def command(track_id, t):
        msg = StrikeCommand()
        msg.track_id = track_id
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(round(t * 1e9), 1_000_000_000)
        show._command(msg)
        return [line.split(':')[0] for line in said]
    assert command(3, 100.0) == ['ball 3']
    assert command(3, 100.3) == ['ball 3']              # the same ball's next command
    assert command(4, 100.4) == ['ball 3', 'ball 4']
    assert command(3, 102.0) == ['ball 3', 'ball 4', 'ball 3']       # another ball, 1.7 s on
    assert command(3, 50.0) == ['ball 3', 'ball 4', 'ball 3', 'ball 3']   # the bag again
