"""Cameras read at their frame rate (tt_perception.camstream): pacing, the driver's buffers,
the bounded queue and the drop counts, checked by frame indices, times of a simulated clock and
frame content (each frame's grey level is its index), never by wall-clock timing."""

import threading

import cv2
import numpy as np
import pytest
from test_sources import empty_avi_frame, overwrite_avi_frame
from tt_perception.camstream import (
    END,
    CameraReader,
    DropCounter,
    Frame,
    FrameQueue,
    LatencyWindow,
    PacedVideoSource,
)

FPS = 100.0
N_FRAMES = 12


class SimClock:
    """A clock that only moves when told: waiting for a deadline jumps to it."""

    def __init__(self, t=0.0):
        self.t = t
        self.waits = []

    def now(self):
        return self.t

    def wait_until(self, deadline, stop):
        self.waits.append(deadline)
        self.t = max(self.t, deadline)
        return stop.is_set()


def grey(n):
    return 10 * n + 20


@pytest.fixture(scope='module')
def video(tmp_path_factory):
    """An MJPG video whose frame n is uniformly grey(n)."""
    path = str(tmp_path_factory.mktemp('video') / 'cam.avi')
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*'MJPG'), FPS, (64, 48))
    for n in range(N_FRAMES):
        writer.write(np.full((48, 64, 3), grey(n), np.uint8))
    writer.release()
    return path


def index_of(image):
    """The frame index encoded in a frame's grey level."""
    return int(round((float(image.mean()) - 20.0) / 10.0))


def test_frames_come_when_due_and_in_order(video):
    clock = SimClock(3.0)
    src = PacedVideoSource(video, FPS, clock=clock, start=5.0).open()
    got = []
    while (n := src.grab()) is not None:
        got.append((n, clock.now(), index_of(src.retrieve())))
    src.close()
    assert [n for n, _, _ in got] == list(range(N_FRAMES))
    # Frame n is handed out exactly when it is due, start + n / fps, not before.
    assert np.allclose([t for _, t, _ in got], 5.0 + np.arange(N_FRAMES) / FPS, atol=1e-12)
    assert [i for _, _, i in got] == list(range(N_FRAMES))      # its own content
    assert src.dropped == 0


def test_a_late_reader_loses_the_overwritten_frames(video):
    clock = SimClock()
    src = PacedVideoSource(video, FPS, clock=clock, buffers=2, start=0.0).open()
    assert src.grab() == 0 and src.grab() == 1
    # The reader is held up: 5.5 frame periods pass before it asks again, so frames 2..6
    # are due; a camera with 2 buffers keeps the newest two (5 and 6) and lost 2, 3, 4.
    clock.t = 6.5 / FPS
    n = src.grab()
    assert n == 5 and index_of(src.retrieve()) == 5
    assert src.take_dropped() == [2, 3, 4] and src.dropped == 3
    assert src.grab() == 6 and index_of(src.retrieve()) == 6
    rest = []
    while (n := src.grab()) is not None:
        rest.append(n)
    assert rest == list(range(7, N_FRAMES))
    assert 2 + 2 + len(rest) + src.dropped == N_FRAMES        # every frame accounted for


def test_full_queue_drops_the_oldest_and_counts_it():
    drops = DropCounter(1)
    q = FrameQueue(3, drops)
    for n in range(5):
        q.put(Frame(0, n, n / FPS))
    q.put(Frame(0, -1, float('nan'), kind=END))       # never dropped, drops nothing
    assert drops.snapshot() == ([2], 2)
    got = [q.get(timeout=0) for _ in range(4)]
    assert [(f.index, f.kind) for f in got] == [(2, 'frame'), (3, 'frame'), (4, 'frame'),
                                                (-1, END)]
    assert q.get(timeout=0) is None
    assert q.high_water == 4


def test_frames_come_out_in_time_order_across_cameras():
    # Camera 0's thread ran ahead of camera 1's; camera 1 is half a frame out of step
    # (offset 5 ms: its frame n is at n / fps + 5 ms on its clock, n / fps on camera 0's).
    drops = DropCounter(2)
    q = FrameQueue(8, drops, offsets=[0.0, 0.005], min_gap=0.5 / FPS)
    for n in range(3):
        q.put(Frame(0, n, n / FPS + 0.002))
    assert q.get(timeout=0) is None           # camera 1 may still send an earlier frame
    for n in range(3):
        q.put(Frame(1, n, n / FPS + 0.005))
    order = [(f.camera, f.index) for f in iter(lambda: q.get(timeout=0), None)]
    # On camera 0's clock: camera 1's frames at 0, 10, 20 ms, camera 0's at 2, 12, 22 ms.
    # Camera 1's next frame cannot come before 25 ms (half a period after its last), so
    # camera 0's last goes at once.
    assert order == [(1, 0), (0, 0), (1, 1), (0, 1), (1, 2), (0, 2)]
    q.put(Frame(0, 3, 0.032))                 # camera 1 may still send one at 25..32 ms
    assert q.get(timeout=0) is None
    q.put(Frame(1, -1, float('nan'), kind=END))
    assert [(f.camera, f.kind) for f in iter(lambda: q.get(timeout=0), None)] == [
        (1, END), (0, 'frame')]               # camera 1 ended: nothing to wait for


def test_a_stalled_camera_is_waited_for_at_most_max_lag():
    drops = DropCounter(2)
    q = FrameQueue(8, drops, max_lag=2.5 / FPS, min_gap=0.5 / FPS)
    q.put(Frame(1, 0, 0.0))
    q.put(Frame(0, 0, 0.0))
    got = [(f.camera, f.index) for f in iter(lambda: q.get(timeout=0), None)]
    assert got == [(0, 0), (1, 0)]
    for n in range(1, 6):                     # camera 1 sends nothing more
        q.put(Frame(0, n, n / FPS))
        got += [(f.camera, f.index) for f in iter(lambda: q.get(timeout=0), None)]
    # Camera 0's frame n is handed out without camera 1 once the newest frame is more than
    # 2.5 periods later, i.e. when frame n + 3 is queued.
    assert got == [(0, 0), (1, 0), (0, 1), (0, 2)]
    assert drops.snapshot() == ([0, 0], 0)


def test_a_pair_counts_once_whichever_cameras_lost_it():
    drops = DropCounter(2)
    drops.drop(0, 7)
    drops.drop(1, 7)         # the same instant: one pair
    drops.drop(1, 8)
    assert drops.snapshot() == ([1, 2], 2)


@pytest.mark.parametrize('queue_size, expect_dropped', [(N_FRAMES + 1, 0), (4, N_FRAMES - 4)])
def test_reader_thread_queues_every_frame_or_counts_it(video, queue_size, expect_dropped):
    # Nobody takes frames from the queue while the thread runs: beyond its size the oldest
    # frames are dropped, and the counts say so.
    drops = DropCounter(1)
    q = FrameQueue(queue_size, drops)
    src = PacedVideoSource(video, FPS, clock=SimClock(), stop=threading.Event(),
                           start=0.0).open()
    reader = CameraReader(0, src, q, drops, stamp=lambda n: n / FPS)
    reader.start()
    reader.join(timeout=30)
    assert not reader.is_alive()
    items = [q.get(timeout=0) for _ in range(len(q))]
    frames = [f for f in items if f.kind != END]
    assert items[-1].kind == END
    assert reader.frames == N_FRAMES
    assert drops.snapshot() == ([expect_dropped], expect_dropped)
    assert len(frames) + expect_dropped == N_FRAMES
    # The frames kept are the newest, each with its own stamp and content.
    kept = list(range(expect_dropped, N_FRAMES))
    assert [f.index for f in frames] == kept
    assert [index_of(f.image) for f in frames] == kept
    assert np.allclose([f.t for f in frames], np.array(kept) / FPS)


def test_reader_runs_after_once_each_frames_detections_are_queued(video):
    # perception_node's background update: after the frame's detections are handed on.
    drops = DropCounter(1)
    q = FrameQueue(N_FRAMES + 1, drops)
    src = PacedVideoSource(video, FPS, clock=SimClock(), stop=threading.Event(),
                           start=0.0).open()
    queued = []
    reader = CameraReader(0, src, q, drops, stamp=lambda n: n / FPS,
                          detect=lambda k, t, image: index_of(image),
                          after=lambda k: queued.append((k, len(q))))
    reader.start()
    reader.join(timeout=30)
    assert not reader.is_alive()
    assert queued == [(0, n + 1) for n in range(N_FRAMES)]
    assert [q.get(timeout=0).detections for _ in range(N_FRAMES)] == list(range(N_FRAMES))


def test_unpaced_lossless_reading_keeps_every_frame(video):
    # video_rate 0 (offline): the reader waits for room in a small queue instead of dropping.
    drops = DropCounter(1)
    stop = threading.Event()
    q = FrameQueue(2, drops, lossless=True, stop=stop)
    src = PacedVideoSource(video, FPS, clock=SimClock(), stop=stop, start=0.0, rate=0.0).open()
    reader = CameraReader(0, src, q, drops, stamp=lambda n: n / FPS)
    reader.start()
    got = []
    while (item := q.get(timeout=30)) is not None and item.kind != END:
        got.append(index_of(item.image))
        assert len(q) <= 2 + 1      # two frames, and the END item (it takes no frame's place)
    reader.join(timeout=30)
    assert got == list(range(N_FRAMES)) and drops.snapshot() == ([0], 0)


@pytest.mark.parametrize('fourcc', ['MJPG', 'XVID'])
def test_a_frame_overwritten_mid_file_is_none_and_the_others_keep_their_index(tmp_path, fourcc):
    # Its packet skipped by FFmpeg's resynchronisation, every later frame had the index (and
    # so the time) of the one before it. Read through the file's index, an XVID frame that
    # failed its grab ended the camera (MJPG's JPEG packets are decoded here instead).
    path = tmp_path / 'cam.avi'
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*fourcc), FPS,
                             (64, 48))
    for n in range(N_FRAMES):
        writer.write(np.full((48, 64, 3), grey(n), np.uint8))
    writer.release()
    overwrite_avi_frame(path, 5)
    src = PacedVideoSource(str(path), FPS, clock=SimClock(), start=0.0, rate=0.0).open()
    got = []
    while (index := src.grab()) is not None:
        image = src.retrieve()
        got.append((index, None if image is None else index_of(image)))
    src.close()
    assert got == [(n, None if n == 5 else n) for n in range(N_FRAMES)]


@pytest.mark.parametrize('rate', [0.0, 1.0])
def test_a_frame_the_file_lacks_is_dropped_and_the_others_keep_their_index(video, tmp_path,
                                                                            rate):
    # An empty chunk (a recorder's dropped frame) is left out by the decoder without failing
    # the grab: every later frame had the index, and so the time, of the one before it.
    path = tmp_path / 'cam.avi'
    path.write_bytes(open(video, 'rb').read())
    empty_avi_frame(path, 5)
    clock = SimClock()
    src = PacedVideoSource(str(path), FPS, clock=clock, start=0.0, rate=rate).open()
    got = []
    while (index := src.grab()) is not None:
        got.append((index, index_of(src.retrieve()), clock.now()))
    src.close()
    assert [(n, i) for n, i, _ in got] == [(n, n) for n in range(N_FRAMES) if n != 5]
    assert src.take_dropped() == [5] and src.dropped == 1
    if rate:
        assert all(t == n / FPS for n, _, t in got)        # each frame when it is due


def test_detection_in_the_camera_thread_gives_the_same_states():
    # Pipeline.detect (run by each camera's thread with the track as the processing thread
    # left it) then process(detections=...) is the sequential pipeline split in two: with the
    # snapshot taken after the previous frame, the states are the same, bit for bit.
    from tt_perception.pipeline import Pipeline

    from tt_perception import synth

    rig = synth.demo_rig()
    frames, _ = synth.render_balls(rig, [synth.incoming_ball(speed=8.0, topspin_rps=30.0)],
                                   [0.0], duration=0.35, lead_in=0.05)
    whole, split = Pipeline(rig), Pipeline(rig)
    a, b = [], []
    for t, k, frame in frames:
        a += whole.process(t, k, frame)
        detections = split.detect(t, k, frame, split.tracker.snapshot())
        b += split.process(t, k, None, detections)
    assert len(a) > 20 and len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x.t == y.t and np.array_equal(x.state, y.state)
        assert np.array_equal(x.covariance, y.covariance) and x.track_id == y.track_id
    bad = split.detect(1.0, 0, np.zeros((4, 4, 3), np.uint8))
    assert isinstance(bad, ValueError)
    assert split.process(1.0, 0, None, bad) == [] and 'frame 4x4, its calibration' in \
        split.last_error


def test_after_warm_up_a_ball_through_the_pipeline_compiles_nothing():
    # The node warms the compiled kernels (numba) before its cameras start: a kernel first
    # called with the ball holds the processing thread for its compilation, or for 30 ms
    # loading it from numba's cache, and frames queue up behind it. The triangulation's
    # covariance came back in Fortran order, and the filter's update loaded a second signature
    # of its kernel on the first ball (27 ms). A fresh process: only warm_up (and the scene's
    # rendering) has compiled.
    import subprocess
    import sys
    code = (
        'import sys\n'
        'from numba.core.registry import CPUDispatcher\n'
        'from tt_prediction.ball_filter import FilterConfig\n'
        'from tt_prediction.params import ModelParams\n'
        'from tt_perception import camera, camstream, detect, pipeline, synth, triangulate\n'
        'from tt_prediction import ball_filter\n'
        'rig = synth.demo_rig()\n'
        'frames, _ = synth.render_balls(rig, [synth.incoming_ball(speed=8.0, topspin_rps=30.0)],\n'
        '                               [0.0], duration=0.5, lead_in=0.05)\n'
        'camstream.warm_up(ModelParams(), FilterConfig())\n'
        'def signatures():\n'
        '    return {f"{m.__name__}.{n}": len(f.signatures) for m in (camera, detect, pipeline,\n'
        '            triangulate, ball_filter) for n, f in vars(m).items()\n'
        '            if isinstance(f, CPUDispatcher)}\n'
        'before = signatures()\n'
        'p = pipeline.Pipeline(rig, tracker_config=pipeline.TrackerConfig(backfill=False))\n'
        'states = 0\n'
        'for t, k, frame in frames:\n'
        '    states += len(p.process(t, k, None, p.detect(t, k, frame, p.tracker.snapshot())))\n'
        'after = signatures()\n'
        'print(states, [n for n in after if after[n] != before[n]])\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    states, compiled = out.stdout.strip().split(' ', 1)
    assert int(states) > 30
    assert compiled == '[]'


def test_absent_device_is_retried_and_loses_nothing():
    # A V4L2 camera that is not there: grab says so (-1) and why, and no frame counts as lost.
    from tt_perception.camstream import open_v4l2

    cam = open_v4l2('/dev/video_tt_absent', reopen_interval=0.0)
    assert cam.grab() == -1 and cam.grab() == -1
    assert 'no such V4L2 device' in cam.source.status
    assert cam.retrieve() is None and cam.dropped == 0 and cam.take_dropped() == []


class FakeCapture:
    """A V4L2 device's OpenCV capture: each grab takes the next buffer timestamp (ms) of a
    script shared by every opening; None: the device stops delivering."""

    def __init__(self, stamps):
        self.stamps = stamps
        self.stamp = 0.0

    def grab(self):
        stamp = self.stamps.pop(0) if self.stamps else None
        if stamp is None:
            return False
        self.stamp = stamp
        return True

    def get(self, prop):
        assert prop == cv2.CAP_PROP_POS_MSEC
        return self.stamp

    def retrieve(self):
        return True, np.full((2, 2, 3), int(self.stamp) % 256, np.uint8)

    def release(self):
        pass


def test_device_frames_lost_by_the_driver_are_counted_and_a_reopening_is_not():
    # Stamps 10 ms apart at 100 fps: 30 ms missing is frame 2 lost; the device then stops,
    # comes back 1 s later and numbering goes on from the next index without counting the
    # second it was away.
    from tt_perception.camstream import V4L2Camera
    from tt_perception.sources import V4L2Source

    stamps = [10.0, 20.0, 40.0, None, 1000.0, 1010.0]

    class FakeDevice(V4L2Source):
        def open(self):
            self.capture = FakeCapture(stamps)
            self.status = f'{self.device}: opened'
            return self

    src = FakeDevice('/dev/video_tt_fake', fps=FPS, reopen_interval=0.0)
    cam = V4L2Camera(src)
    got = []
    for _ in range(6):
        index = cam.grab()
        image = cam.retrieve()
        got.append((index, None if image is None else int(image[0, 0, 0]), src.status))
    assert got == [(0, 10, '/dev/video_tt_fake: opened'), (1, 20, '/dev/video_tt_fake: opened'),
                   (3, 40, '/dev/video_tt_fake: opened'),
                   (-1, None, '/dev/video_tt_fake: camera stopped delivering frames, reopening'),
                   (4, 1000 % 256, '/dev/video_tt_fake: reopened'),
                   (5, 1010 % 256, '/dev/video_tt_fake: reopened')]
    assert cam.dropped == 1 and cam.take_dropped() == [2]
    assert cam.t == pytest.approx(1.010 + src._clock_offset)
    # read() is grab and retrieve: the frame and the same wall-clock stamp.
    stamps[:] = [1020.0]
    t, frame = src.read()
    assert t == pytest.approx(1.020 + src._clock_offset) and int(frame[0, 0, 0]) == 1020 % 256
    assert src.read() == (None, None) and 'stopped delivering' in src.status


def test_device_frames_are_numbered_at_the_rate_the_driver_gives():
    # Asked for the rig's 150 fps, the driver gives 30 (it says so after opening): its frames,
    # 33.3 ms apart, are one after the other, none lost. Numbered at 150 fps, 4 frames that
    # never existed counted lost for each (476 frame pairs dropped for 120 frames read).
    from tt_perception.camstream import V4L2Camera
    from tt_perception.sources import V4L2Source

    stamps = [1000.0 + n * 1000.0 / 30.0 for n in range(6)]

    class SlowDevice(V4L2Source):
        def open(self):
            self.capture = FakeCapture(stamps)
            self.driver_fps = 30.0
            self.status = f'{self.device}: opened'
            return self

    cam = V4L2Camera(SlowDevice('/dev/video_tt_fake', fps=150.0, reopen_interval=0.0))
    assert [cam.grab() for _ in range(6)] == list(range(6))
    assert cam.dropped == 0 and cam.take_dropped() == []


def test_latency_window_gives_the_percentiles_of_the_last_values():
    # Its percentiles are numpy's of the last `size` values added, in ms, before and after
    # the ring wraps; none added: nan.
    window = LatencyWindow(size=50)
    assert all(np.isnan(window.percentiles_ms()))
    values = np.random.default_rng(2).exponential(0.004, 130)
    for n, v in enumerate(values, 1):
        window.add(v)
        if n in (1, 37, 50, 51, 130):
            last = values[max(0, n - 50):n]
            assert window.percentiles_ms((50, 99)) == pytest.approx(
                1e3 * np.percentile(last, [50, 99]), rel=1e-12)
    assert window.count == 130
