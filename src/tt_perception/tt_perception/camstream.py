"""Cameras read in-process at their frame rate: a reader thread per camera, a bounded queue to
the processing thread, and honest counts of every frame that is lost on the way.

This is how perception_node reads cameras on the robot (V4L2 devices) and how it plays video
files as if they were cameras (paced at the rig's fps). Pure module (no rclpy).

- :class:`PacedVideoSource`: a video file (or image sequence) that delivers frame n at
  ``start + n / fps`` on a clock, as a camera does. Its driver has ``buffers`` frame buffers:
  a reader more than ``buffers`` frames late finds the older frames overwritten; they are
  skipped (never decoded) and counted as dropped. MJPG video is read as the camera's JPEG
  packets (``cv2.CAP_PROP_FORMAT`` -1) and decoded in :meth:`retrieve`, as a V4L2 MJPG camera's
  frames are, so that a skipped frame costs no decoding.
- :class:`V4L2Camera`: a :class:`tt_perception.sources.V4L2Source` behind the same
  ``grab``/``retrieve`` interface; frames the driver lost are counted from gaps in the buffer
  timestamps.
- :class:`FrameQueue`: bounded queue from the readers to the processing thread; when it is
  full the oldest frame is dropped (the freshest frames matter for a ball in flight) and
  counted.
- :class:`DropCounter`: frames lost per camera, and the frame pairs (instants) that lost at
  least one camera's frame.
- :class:`CameraReader`: the thread of one camera (grab, stamp, retrieve, detect, queue).

Times: a frame's ``t`` (s) is its exposure time. A V4L2 camera's is the driver's buffer
timestamp on the wall clock; a paced file's is ``stamp(index)`` of its :class:`CameraReader`,
which perception_node makes video time (``n / fps``) or, with ``video_clock: wall``, the
wall-clock time at which the paced frame is exposed (video start + ``n / fps``), as a live
camera's stamps are. ``index`` is the frame number since the source opened (the instant a
pair is made of).
"""

import collections
import dataclasses
import os
import threading
import time

import cv2
import numpy as np
from tt_prediction.ball_filter import BallFilter

from . import detect, pipeline, triangulate
from .sources import V4L2Source, VideoFileSource

END = 'end'
"""``Frame.kind`` of the item a reader queues after the last frame of a file."""
STAGE_WINDOW = 3000
"""Frames over which the time of a stage (a camera's decoding, detection; processing) is
given as percentiles: 10 s of two cameras at 150 fps."""


@dataclasses.dataclass
class Frame:
    """One camera frame on its way to the processing thread."""

    camera: int
    index: int
    """Frame number since the source opened."""
    t: float
    """Exposure time of the frame, s (video time, or wall clock for live stamps)."""
    image: np.ndarray = None
    """BGR uint8 image; None for a lost or unreadable frame (or once detected)."""
    kind: str = 'frame'
    detections: object = None
    """What the camera's thread detected in it (``CameraReader(detect=...)``), or None."""


class MonotonicClock:
    """The clock paced sources run on: ``now()`` (s, CLOCK_MONOTONIC) and
    ``wait_until(deadline, stop)`` (returns True when ``stop`` was set meanwhile)."""

    @staticmethod
    def now():
        return time.monotonic()

    @staticmethod
    def wait_until(deadline, stop):
        while True:
            left = deadline - time.monotonic()
            if left <= 0.0:
                return stop.is_set()
            if stop.wait(left):
                return True


class DropCounter:
    """Frames lost per camera and the instants (frame pairs) that lost at least one frame.

    Thread-safe. An instant is a frame index (cameras of a rig run at the same rate, their
    frames n make pair n)."""

    def __init__(self, n_cameras, memory=4096):
        self.frames = [0] * n_cameras
        self.pairs = 0
        self._lock = threading.Lock()
        self._recent = collections.OrderedDict()
        self._memory = memory

    def drop(self, camera, index):
        with self._lock:
            self.frames[camera] += 1
            if index in self._recent:
                return
            self.pairs += 1
            self._recent[index] = True
            while len(self._recent) > self._memory:
                self._recent.popitem(last=False)

    def snapshot(self):
        with self._lock:
            return list(self.frames), self.pairs


class FrameQueue:
    """Bounded queues of :class:`Frame`, one per camera, from the camera threads to the
    processing thread, which takes the frames in time order across the cameras.

    ``put`` never blocks a camera: when its queue holds ``maxsize`` frames the oldest is
    dropped and counted in ``drops``. With ``lossless`` (video files read as fast as they are
    processed) ``put`` waits for room instead, until ``stop`` is set. An END item (after a
    camera's last frame) is never dropped and takes no frame's place.

    ``get`` returns the earliest frame (time ``t`` minus the camera's ``offsets`` entry) once
    no other camera can still send an earlier one: each camera that has not ended has a frame
    queued, or its next frame cannot be earlier (frames come at least ``min_gap`` s apart,
    half a frame period for cameras at the same rate, so a pair's second frame goes on at
    once); a camera that lags (its newest frame ``max_lag`` s behind the newest of all, e.g.
    a device that stopped) is not waited for. ``max_lag`` None: always wait (lossless files).
    ``cameras``: the indices that put frames here (default all).
    """

    def __init__(self, maxsize, drops, lossless=False, stop=None, offsets=None, max_lag=None,
                 cameras=None, min_gap=0.0):
        self.maxsize = int(maxsize)
        self.drops = drops
        self.lossless = lossless
        self.stop = stop or threading.Event()
        n = len(drops.frames)
        self.offsets = list(offsets) if offsets is not None else [0.0] * n
        self.max_lag = max_lag
        self._items = [collections.deque() for _ in range(n)]
        self._ended = set(range(n)) - set(range(n) if cameras is None else cameras)
        self._newest = -np.inf
        self._last = [-np.inf] * n            # newest frame time put per camera
        self.min_gap = float(min_gap)
        self._cond = threading.Condition()
        self.high_water = 0

    def put(self, frame):
        k = frame.camera
        with self._cond:
            items = self._items[k]
            if frame.kind != END:
                while self.lossless and len(items) >= self.maxsize and not self.stop.is_set():
                    self._cond.wait(0.1)
                while len(items) >= self.maxsize and items[0].kind != END:
                    old = items.popleft()
                    self.drops.drop(old.camera, old.index)
                self._newest = max(self._newest, frame.t - self.offsets[k])
                self._last[k] = frame.t - self.offsets[k]
            items.append(frame)
            self.high_water = max(self.high_water, len(items))
            self._cond.notify_all()

    def _pick(self):
        """The camera whose head item is to be handed out now, or None."""
        heads = []
        for k, items in enumerate(self._items):
            if items:
                if items[0].kind == END:
                    return k
                heads.append((items[0].t - self.offsets[k], k))
        if not heads:
            return None
        t, k = min(heads)
        waiting = any(not items and j not in self._ended
                      and self._last[j] + self.min_gap <= t
                      for j, items in enumerate(self._items))
        if waiting and (self.max_lag is None or self._newest - t <= self.max_lag):
            return None
        return k

    def get(self, timeout=None):
        """The next frame in time order (or an END item), or None after ``timeout`` s."""
        with self._cond:
            if self._pick() is None and not self._cond.wait_for(
                    lambda: self._pick() is not None, timeout):
                return None
            item = self._items[self._pick()].popleft()
            if item.kind == END:
                self._ended.add(item.camera)
            self._cond.notify_all()          # a lossless reader waiting for room
            return item

    def __len__(self):
        with self._cond:
            return sum(len(items) for items in self._items)


class PacedVideoSource:
    """A video file or image sequence delivered at its frame rate, as a camera delivers.

    ``grab()`` waits until the next frame is due (frame n at ``start + n / fps`` on
    ``clock``), skips the frames a camera with ``buffers`` buffers would have overwritten
    meanwhile (counted in ``dropped``), and returns the frame's index, or None at the end
    of the file or when ``stop`` is set. A frame the file does not hold (an empty chunk of an
    AVI, some recorders' dropped frame) is counted in ``dropped`` too, and the frames after
    it keep their indices. ``retrieve()`` decodes that frame (BGR uint8).
    ``start`` is set by the first ``grab`` unless given. ``rate``: playback speed (1: real
    time, as a camera; 0: no pacing and no loss, each frame as soon as it is asked for).
    """

    def __init__(self, path, fps, clock=None, buffers=2, stop=None, start=None, rate=1.0):
        self.path = path
        self.fps = float(fps)
        self.rate = float(rate)
        self.clock = clock or MonotonicClock()
        self.buffers = max(1, int(buffers))
        self.stop = stop or threading.Event()
        self.start = start
        self.index = -1          # frame number of the last grab
        self.dropped = 0
        self.dropped_indices = []    # the skipped frame numbers since the last call of take
        self._file = None
        self._raw = False
        self._lost = False       # the last grab failed on a frame the file's index has

    def _grab(self, cap, index):
        """``cap.grab()`` of frame ``index``: the index of the frame grabbed, or None at the
        end. Read through an AVI's index (:class:`VideoFileSource` ``by_index``) a grab that
        fails on a frame the index lists gives ``index`` (a damaged frame fails its read
        alone, the next goes on; :meth:`retrieve` then gives None), and the frame grabbed is
        numbered from its PTS (:meth:`VideoFileSource.grabbed_number`): past ``index`` when
        the file does not hold the frames before it."""
        self._lost = not cap.grab()
        if self._lost:
            return index if self._file.by_index and index < self._file.declared else None
        return self._file.grabbed_number(index)

    def _skip(self, first, end):
        """Count frames ``first`` to ``end`` - 1 as dropped."""
        self.dropped += end - first
        self.dropped_indices.extend(range(first, end))

    def open(self):
        src = VideoFileSource(self.path, self.fps)
        src.open()
        cap = src.capture
        fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, 'little')
        if fourcc == b'MJPG' and os.path.isfile(self.path):
            # The JPEG packets as a camera sends them; decoded in retrieve().
            self._raw = bool(cap.set(cv2.CAP_PROP_FORMAT, -1))
        self._file = src
        return self

    def due(self, index):
        """Clock time (s) at which frame ``index`` is exposed (paced playback)."""
        return self.start + index / (self.fps * self.rate)

    def grab(self):
        """Index of the next frame, once it is due; None at the end or when stopped."""
        cap = self._file.capture
        if self.start is None:
            self.start = self.clock.now()
        nxt = self.index + 1
        if self.rate <= 0.0:
            got = None if self.stop.is_set() else self._grab(cap, nxt)
        else:
            if self.clock.wait_until(self.due(nxt), self.stop):
                return None
            # Frames due before the newest `buffers` ones were overwritten in the driver's
            # ring.
            newest = int(np.floor((self.clock.now() - self.start) * self.fps * self.rate
                                  + 1e-9))
            while nxt < newest - self.buffers + 1:
                got = self._grab(cap, nxt)
                if got is None:
                    return None
                self._skip(nxt, got + 1)
                nxt = got + 1
            got = self._grab(cap, nxt)
            if (got is not None and got > nxt
                    and self.clock.wait_until(self.due(got), self.stop)):
                return None             # a frame the file lacks: the next one comes when due
        if got is None:
            return None
        self._skip(nxt, got)
        self.index = got
        return got

    def take_dropped(self):
        """The frame numbers skipped since the last call."""
        out, self.dropped_indices = self.dropped_indices, []
        return out

    def retrieve(self):
        """The grabbed frame, BGR uint8, or None when it cannot be decoded."""
        if self._lost:
            return None
        ok, data = self._file.capture.retrieve()
        if not ok or data is None:
            return None
        if self._raw:
            return cv2.imdecode(data.reshape(-1), cv2.IMREAD_COLOR)
        return data

    def disagreement(self, cam, rig_fps):
        """:meth:`tt_perception.sources.VideoFileSource.disagreement` of the opened file."""
        return self._file.disagreement(cam, rig_fps)

    def close(self):
        if self._file is not None:
            self._file.close()
            self._file = None


class V4L2Camera:
    """A V4L2 device behind the ``grab``/``retrieve`` interface of :class:`PacedVideoSource`.

    ``grab()`` returns the frame's index (frames since the first, from the buffer
    timestamps) or None while the device is away; the frames the driver lost show as gaps of
    the timestamps and are counted in ``dropped``. The frames are numbered at the rate the
    driver says it runs at (``source.driver_fps``), else at the one asked (``source.fps``, the
    rig's): a 30 fps camera numbered at 150 fps had 4 frames that never existed counted lost
    for each it gave. ``t`` is the grabbed frame's wall-clock time (the driver's buffer
    timestamp)."""

    def __init__(self, source, stop=None):
        self.source = source
        self.fps = source.fps
        self.stop = stop or threading.Event()
        self.index = -1
        self.t = None
        self.dropped = 0
        self.dropped_indices = []
        self._t0 = None
        self._grabbed = False

    def open(self):
        return self

    def grab(self):
        """Index of the next frame once the driver has it; -1 while the device is away (it
        is reopened every ``reopen_interval``, ``source.status`` says what happened)."""
        self._grabbed = False
        t = self.source.grab()
        if t is None:
            return -1
        if self._t0 is None or self.source.reopened:
            # Frames while the device was away are not drops of this node: count on.
            self.fps = getattr(self.source, 'driver_fps', 0.0) or self.source.fps
            self._t0 = t - (self.index + 1) / self.fps
        index = max(int(round((t - self._t0) * self.fps)), self.index + 1)
        for lost in range(self.index + 1, index):
            self.dropped += 1
            self.dropped_indices.append(lost)
        self.index, self.t, self._grabbed = index, t, True
        return index

    def take_dropped(self):
        out, self.dropped_indices = self.dropped_indices, []
        return out

    def retrieve(self):
        return self.source.retrieve() if self._grabbed else None

    def close(self):
        self.source.close()


class CameraReader(threading.Thread):
    """The thread of one camera: grab a frame when it comes, stamp it, decode it, queue it.

    ``source``: a :class:`PacedVideoSource` or :class:`V4L2Camera`. ``stamp(index)`` gives a
    frame's time (s) from its index (paced files); for a V4L2 camera the driver's timestamp is
    used. Frames the source lost are counted in ``drops``; an END item is queued after the
    last frame of a file. ``on_status(text)`` reports a device's state changes.
    ``detect(camera, t, image)``: run on each frame in this thread (the ball detection of
    this camera, in parallel with the other cameras and the processing thread); its result
    is queued as ``Frame.detections`` in place of the image. ``ready(camera, t)``: run before
    ``detect``, outside its time (perception_node waits there for the processing thread at a
    track's start). ``after(camera)``: run once the frame's detections are queued, for what
    need not delay them (the detector's background update)."""

    def __init__(self, camera, source, queue, drops, stamp=None, on_status=None, on_error=None,
                 detect=None, ready=None, after=None):
        super().__init__(daemon=True, name=f'camera-{camera}')
        self.camera = camera
        self.source = source
        self.queue = queue
        self.drops = drops
        self.stamp = stamp
        self.on_status = on_status
        self.on_error = on_error
        self.detect = detect
        self.ready = ready
        self.after = after
        self.frames = 0
        self.read_time = LatencyWindow(STAGE_WINDOW)
        """Time to take each grabbed frame's image (retrieve: decoding an MJPG frame), s."""
        self.detect_time = LatencyWindow(STAGE_WINDOW)
        """Time of ``detect`` on each frame, s."""
        self.stop_event = source.stop

    def run(self):
        status = ''
        try:
            while not self.stop_event.is_set():
                index = self.source.grab()
                for lost in self.source.take_dropped():
                    self.drops.drop(self.camera, lost)
                inner = getattr(self.source, 'source', None)
                if inner is not None and self.on_status and inner.status != status:
                    status = inner.status
                    self.on_status(self.camera, status)
                if index is None:
                    break
                if index < 0:                       # a device away: retried by grab
                    self.stop_event.wait(0.01)
                    continue
                t = self.stamp(index) if self.stamp else self.source.t
                start = time.perf_counter()
                image = self.source.retrieve()
                read = time.perf_counter()
                self.read_time.add(read - start)
                self.frames += 1
                if self.detect is not None:
                    if self.ready is not None:
                        self.ready(self.camera, t)
                        read = time.perf_counter()
                    detections = self.detect(self.camera, t, image)
                    self.detect_time.add(time.perf_counter() - read)
                    self.queue.put(Frame(self.camera, index, t, detections=detections))
                    if self.after is not None:
                        self.after(self.camera)
                else:
                    self.queue.put(Frame(self.camera, index, t, image))
        except Exception as exc:  # noqa: BLE001 - reported by the node, the thread ends
            if self.on_error:
                self.on_error(self.camera, exc)
        finally:
            self.source.close()
            if not self.stop_event.is_set():
                self.queue.put(Frame(self.camera, -1, float('nan'), None, kind=END))

    def stop(self):
        self.stop_event.set()


class LatencyWindow:
    """The last ``size`` durations (s), thread-safe; percentiles in ms.

    Held in a ring of floats, so that the percentiles (on /diagnostics, once a second) copy
    one array rather than convert a queue of Python floats (0.6 ms under the GIL for 20000,
    a stall of the camera threads)."""

    def __init__(self, size=20000):
        self._values = np.empty(int(size))
        self._lock = threading.Lock()
        self.count = 0

    def add(self, seconds):
        with self._lock:
            self._values[self.count % self._values.size] = seconds
            self.count += 1

    def percentiles_ms(self, qs=(50, 99)):
        with self._lock:
            if not self.count:
                return [float('nan')] * len(qs)
            values = self._values[:min(self.count, self._values.size)].copy()
        return [float(v) * 1e3 for v in np.percentile(values, qs)]


def open_v4l2(device, **kwargs):
    """A :class:`V4L2Camera` of the V4L2Source built from ``device`` and ``kwargs``."""
    return V4L2Camera(V4L2Source(device, **kwargs))


def warm_up(params, filter_config, fps=150.0):
    """Run the filter once through a flight with a bounce, and the detector's outline model,
    the ball's expected image and the triangulation once, so that their compiled kernels
    (numba) are loaded before the cameras start rather than on the first ball's frames (which
    would otherwise queue up behind them and be dropped)."""
    f = BallFilter(params, filter_config)
    f.start(0.0, np.array([0.0, 0.0, 0.3]), np.array([-5.0, 0.0, 0.0]), np.eye(3) * 1e-6,
            np.eye(3) * 1e-2)
    for i in range(1, int(0.4 * fps)):
        f.predict(i / fps)
        f.update(f.x[:3].copy(), np.eye(3) * 1e-6)
    f.innovation(f.x[:3].copy(), np.eye(3) * 1e-6)
    f.update_spin(np.zeros(3), np.eye(3) * 100.0)
    detect.warm_up()
    pipeline.warm_up()
    triangulate.warm_up()
