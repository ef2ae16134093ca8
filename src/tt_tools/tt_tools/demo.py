"""`make demo`: the robot's three nodes on a recording, as separate `ros2 run` processes.

1. Builds (once, cached) the demo recording: two synthetic 150 fps cameras watching several
   incoming balls, as MJPG videos and as a rosbag2 bag (sensor_msgs/Image + CameraInfo), with
   the truth.
2. Starts prediction, strike and `ros2 bag record` on their outputs with `ros2 run` (nice 5:
   they and this collector yield the cores to perception's cameras, YIELD_NICE), then
   perception: on the robot's configuration (``--source video``, the default) it reads the
   videos itself as cameras at 1.0x real time (frames paced at 150 fps, stamped with the
   wall-clock exposure time); with ``--source topics`` it subscribes the image topics and the
   bag is replayed with `ros2 bag play --rate R` (0.15 by default).
3. Prints a table per ball (truth vs perceived state, predicted vs true bounce zone and hit
   point, the strike command and where the ball would really land), writes a PNG (top and side
   views) and shows `ros2 bag info` of the session bag.

Usage: python -m tt_tools.demo [--out DIR] [--balls N] [--source video|topics] [--rate R]
                               [--target-zone Z] [--hit-plane-x X] [--imaging clean|hall]
                               [--ball white|orange]
"""

import argparse
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

from tt_prediction.cli import hit_plane_error
from tt_ros.rosenv import domain_id_error

from .procs import ProcessGroup, ros_env, wait_until
from .recording import COLOURS, IMAGING

OUTPUT_TOPICS = ('/ball/state', '/ball/prediction', '/strike/command')
YIELD_NICE = 5
"""Niceness of prediction, strike, the recorder and this collector while perception reads the
cameras (at 1.0x): the camera path loses frames when it waits for a core; the others only
answer a little later. On the robot give perception its cores (docs/perception.md)."""


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='python -m tt_tools.demo',
                                     description=__doc__.splitlines()[0].replace('`', ''))
    parser.add_argument('--out', default='out/demo', help='output folder (default out/demo)')
    parser.add_argument('--balls', type=int, default=4, help='incoming balls (default 4)')
    parser.add_argument('--source', choices=('video', 'topics'), default='video',
                        help='video (default): perception reads the cameras (videos) itself '
                             'at real time, as on the robot; topics: the images go over DDS '
                             'from ros2 bag play')
    parser.add_argument('--rate', type=float, default=None,
                        help='playback rate (default 1.0 with --source video; 0.15 with '
                             '--source topics: 0.9 MB images through Python nodes on a busy '
                             '2-core machine)')
    parser.add_argument('--target-zone', type=int, default=5,
                        help='zone 1..9 the strike aims at (default 5)')
    parser.add_argument('--hit-plane-x', type=float, default=-1.5,
                        help='hitting plane x, m (default -1.5)')
    parser.add_argument('--imaging', choices=IMAGING, default='clean',
                        help="the recording's rendering: clean (default), the flat-lit ball; "
                             "hall, a hall's camera (overhead light with shading and "
                             'highlight, contact shadow, vignetting, shot noise, JPEG q30, '
                             '2 ms blur)')
    parser.add_argument('--ball', choices=COLOURS, default='white',
                        help="the balls' colour (default white); perception is told it "
                             '(ball_colour)')
    args = parser.parse_args(argv)
    if not 1 <= args.target_zone <= 9:
        parser.error(f'--target-zone must be 1..9, got {args.target_zone}')
    if args.rate is None:
        args.rate = 1.0 if args.source == 'video' else 0.15
    if args.balls < 1:
        parser.error(f'--balls must be 1 or more, got {args.balls}')
    if not args.rate > 0.0:
        parser.error(f'--rate must be above 0, got {args.rate:g}')
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        parser.error(f'--out {args.out}: not a folder')
    plane_error = hit_plane_error(args.hit_plane_x)     # the prediction node's range
    if plane_error:
        parser.error(plane_error)
    from .scenario import demo_balls
    try:                      # the recording's balls (ms; before anything is written)
        demo_balls(args.balls, args.hit_plane_x)
    except RuntimeError as exc:
        parser.error(f'--hit-plane-x {args.hit_plane_x:g}: {exc}')
    return args


STARTED = time.monotonic()


def say(text):
    """A progress line with the time since the demo started."""
    print(f'tt-demo [{time.monotonic() - STARTED:5.1f} s]: {text}', flush=True)


def finish(group, collector, log_dir):
    """Wait until the outputs go quiet (the last frames are still in the pipeline when the
    input ends), then stop the recorder and the nodes; a bad exit is a warning."""
    wait_until(lambda: collector.spin_once() or collector.quiet_for(2.0), 60.0,
               'the graph to finish the last ball')
    say('outputs quiet; stopping the recorder and the nodes')
    for name in ('record', 'strike', 'prediction', 'perception'):
        code = group.stop(name)
        if code not in (0, -2, 130):
            print(f'tt-demo: warning: {name} exited with {code} (see {log_dir}/{name}.log)',
                  file=sys.stderr)


def start_outputs(group, session, args, wall_stamps):
    """Start prediction, strike and `ros2 bag record` of their outputs. ``wall_stamps``:
    the states are stamped with the wall-clock exposure time, as on the robot; otherwise
    (video time, or the recording's stamps replayed at ``--rate``) prediction has no
    ``stale_after_s`` and strike no ``check_hit_time``."""
    nice = ['nice', '-n', str(YIELD_NICE)]          # perception comes first
    group.start('prediction', [*nice, 'ros2', 'run', 'tt_prediction', 'prediction_node',
                               '--ros-args', '-p', f'hit_plane_x:={args.hit_plane_x}']
                + ([] if wall_stamps else ['-p', 'stale_after_s:=0.0']))
    # The report strikes the true ball at the prediction's plane: use_hit_plane.
    group.start('strike', [*nice, 'ros2', 'run', 'tt_strike', 'strike_node', '--ros-args',
                           '-p', f'target_zone:={args.target_zone}', '-p', 'use_hit_plane:=true']
                + ([] if wall_stamps else ['-p', 'check_hit_time:=false']))
    group.start('record', [*nice, 'ros2', 'bag', 'record', '-o', str(session), *OUTPUT_TOPICS])


def run_graph_video(rec, session, log_dir, args, collector):
    """The robot's configuration: prediction, strike and the recorder first, then perception
    reading the recording's videos as cameras (paced at their fps times ``--rate``, live
    wall-clock stamps at 1.0x); collect the outputs. Returns (video start as a wall time, s;
    perception's last diagnostics)."""
    from tt_perception.camera import load_rig
    from tt_perception.node import CAMERAS_DIAGNOSTIC

    cameras = str(len(load_rig(str(rec.video_rig)).cameras))
    diags = collector.watch_diagnostics(CAMERAS_DIAGNOSTIC)
    live = args.rate == 1.0
    with ProcessGroup(str(log_dir)) as group:
        start_outputs(group, session, args, wall_stamps=live)
        # /ball/state: prediction and this collector; the recorder subscribes once it sees
        # perception's publisher: perception waits for all three (wait_for_subscribers).
        wait_until(lambda: collector.spin_once() or collector.graph_ready(state_subscribers=2),
                   90.0, f'prediction, strike and the recorder to join the graph (see '
                   f'{log_dir}/*.log)')
        say(f'prediction, strike and recorder up; perception reads {rec.video_rig.parent.name}'
            f"'s videos as cameras at {args.rate}x real time")
        group.start('perception', [
            'ros2', 'run', 'tt_perception', 'perception_node', '--ros-args',
            '-p', f'rig_file:={rec.video_rig}', '-p', f'video_rate:={args.rate}',
            '-p', f'video_clock:={"wall" if live else "video"}',
            '-p', 'wait_for_subscribers:=3', '-p', f'ball_colour:={rec.colour}'])
        os.nice(YIELD_NICE)      # this collector too yields to the cameras
        wait_until(lambda: collector.spin_once() or diags.get('cameras_ended') == cameras,
                   600.0, f'perception to play the videos (see {log_dir}/perception.log)')
        say('videos done')
        finish(group, collector, log_dir)
    start = float(diags['video_start_wall_s'])
    return (start if live else 0.0), diags


def run_graph(recording, session, log_dir, args, collector):
    """Run the three nodes and the recorder while the recording plays; collect the outputs."""
    rig = recording / 'rig.yaml'
    with ProcessGroup(str(log_dir), large_messages=True) as group:
        group.start('perception', ['ros2', 'run', 'tt_perception', 'perception_node',
                                   '--ros-args', '-p', f'rig_file:={rig}',
                                   '-p', f'ball_colour:={args.ball}'])
        start_outputs(group, session, args, wall_stamps=False)   # the recording's stamps
        wait_until(lambda: collector.spin_once() or collector.graph_ready(), 90.0,
                   'the three nodes and the recorder to join the graph (see '
                   f'{log_dir}/*.log)')
        say(f'nodes up; replaying {recording.name} at rate {args.rate}')
        player = group.start('play', ['ros2', 'bag', 'play', str(recording / 'bag'),
                                      '--rate', str(args.rate), '--wait-for-subscribers'])
        wait_until(lambda: collector.spin_once() or player.poll() is not None, 600.0,
                   'the replay to finish')
        if player.returncode != 0:
            raise RuntimeError(f'ros2 bag play failed (exit {player.returncode}), see '
                               f'{log_dir}/play.log')
        say('replay done')
        finish(group, collector, log_dir)


def show_bag_info(session):
    """Print `ros2 bag info` of the session bag (proves it reads back)."""
    result = subprocess.run(['ros2', 'bag', 'info', str(session)], env=ros_env(),
                            capture_output=True, text=True, timeout=60)
    print(result.stdout.rstrip() or result.stderr.rstrip())
    return result.returncode


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def main(argv=None):
    """The demo; Ctrl-C, SIGTERM or SIGHUP stop its nodes (the session bag closed) and
    exit 130 with one line."""
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _interrupt)
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print('tt-demo: interrupted', file=sys.stderr)
        return 130


def _main(argv):
    args = parse_args(argv)
    error = domain_id_error()
    if error:
        print(f'demo: {error}', file=sys.stderr)
        return 2
    os.environ.update(ros_env(large_messages=True))
    out = pathlib.Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    from . import demo_report, recording
    from .collector import Collector

    rec = recording.ensure_recording(out / 'recording', balls=args.balls,
                                     hit_plane_x=args.hit_plane_x, imaging=args.imaging,
                                     colour=args.ball)
    session = out / 'session'
    if session.exists():
        say(f"replacing the previous run's session bag {session} and logs in {out / 'logs'}")
    shutil.rmtree(session, ignore_errors=True)
    log_dir = out / 'logs'
    shutil.rmtree(log_dir, ignore_errors=True)      # a --source topics run's play.log stayed
    log_dir.mkdir()
    if args.source == 'video':
        with Collector() as collector:
            start, diags = run_graph_video(rec, session, log_dir, args, collector)
            # Stamps: the wall time at which video time 0 was exposed (1.0x), or video time.
            outputs = demo_report.shift_times(collector.outputs(), start - rec.video_t0)
        if args.rate == 1.0:
            latency = (f"exposure -> /ball/state latency p50 {diags.get('latency_p50_ms')} ms, "
                       f"p99 {diags.get('latency_p99_ms')} ms")
        else:       # stamps in video time (it said nan ms; a walk-through)
            latency = f'no latency measured at --rate {args.rate:g} (stamps in video time)'
        say(f"perception: {diags.get('frames_processed')} frames, "
            f"{diags.get('frame_pairs_dropped')} frame pairs dropped, {latency}")
    else:
        with Collector(rec.image_topics) as collector:
            run_graph(rec.path, session, log_dir, args, collector)
            outputs = demo_report.shift_times(collector.outputs(), recording.STAMP_BASE_S)
    results = demo_report.evaluate(rec.truths, outputs, rec.params)
    say('nodes stopped; the balls against the truth:')
    print(demo_report.format_table(results, args.target_zone))
    png = demo_report.plot(results, rec.params, out / 'demo.png')
    say(f'wrote {png}')
    say(f'session bag {session} (ros2 bag play {session} --topics /strike/command '
        '--wait-for-subscribers, beside a subscriber):')
    failed = demo_report.balls_missed(results)
    if show_bag_info(session) != 0:
        failed.append(f'ros2 bag info cannot read the session bag {session}')
    if failed:
        dropped = (f"; perception dropped {diags.get('frame_pairs_dropped')} frame pairs"
                   if args.source == 'video' else '')
        say(f'FAILED: {"; ".join(failed)}{dropped} (logs in {log_dir})')
        return 1
    say('done')
    return 0


if __name__ == '__main__':
    sys.exit(main())
