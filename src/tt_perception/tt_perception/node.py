"""perception_node: ball state from the rig's cameras, published on /ball/state.

ROS glue only (the math is in the pure modules). Each camera of the rig file comes from its
``source``: an image topic (sensor_msgs/Image on the source, CameraInfo on the sibling
``camera_info`` topic, sensor-data QoS), a V4L2 device (a thread per device) or a video file
(one thread reads the files together, paced at the rig's fps; times are video times, from 0,
published on /clock with ``publish_clock`` so that nodes with ``use_sim_time`` share them;
the frame-draining timer runs on the steady clock).
Every
frame goes through :class:`tt_perception.pipeline.Pipeline`; each estimate is published as
tt_msgs/BallState stamped with the exposure time of the camera-0 frame it derives from (the
image header stamp), 9x9 covariance row-major (position, velocity, spin).

Bad input never produces a state: a missing or invalid rig file is logged and the node stays
idle; a CameraInfo that disagrees with the calibration disables that camera with an error; a
frame of the wrong size or encoding is dropped with a warning; a camera that stops delivering
is reported (and a device reopened) while the node keeps running.
"""

import math
import queue
import threading
import time

from geometry_msgs.msg import Vector3Stamped
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import CameraInfo, Image
from tt_prediction.params import load_model
from tt_ros.executor import run_node
from tt_ros.messages import set_time, set_xyz
from tt_ros.parameters import Param, Parameters

from tt_msgs.msg import BallState

from .camera import CalibrationError, load_rig
from .detect import DetectorConfig
from .estimator import FilterConfig
from .pipeline import Pipeline, TrackerConfig
from .sources import V4L2Source, camera_info_topic, file_frames, image_to_bgr, source_kind

STATE_TOPIC = '/ball/state'
SUBSCRIBER_POLL_S = 0.05
"""How often the video reader looks for the subscriptions it waits for, s."""


# Read once at start (the rig and the pipeline are built from them): read-only.
PARAMETERS = tuple(Param(*spec, read_only=True) for spec in (
    ('rig_file', '', 'Rig file (DESIGN.md): camera poses, camera_info files and sources'),
    ('model_file', '', 'Ball model YAML written by tt-identify (empty: nominal model)'),
    ('ball_colour', 'any', 'Ball colour', '', None, None, ('white', 'orange', 'any')),
    ('diff_threshold', 22.0, 'Grey-level change against the background of a ball pixel', '',
     2, 200),
    ('min_area', 4, 'Smallest ball blob', 'pixels', 1, 10000),
    ('max_area', 900, 'Largest ball blob (near, motion-blurred)', 'pixels', 4, 1000000),
    ('max_width', 30.0, 'Largest ball diameter in the image', 'pixels', 2, 1000),
    ('roi_half_size', 40, 'Half size of the search window around the predicted ball',
     'pixels', 8, 2000),
    ('pixel_sigma', 0.15, 'Standard deviation of a detected centre', 'pixels', 0.01, 10),
    ('max_reprojection', 2.5, 'Largest reprojection error of a triangulated ball', 'pixels',
     0.1, 50),
    ('accel_noise', 0.05, 'Unmodelled acceleration of the filter', 'm/s^2/sqrt(Hz)', 0.0, 100),
    ('spin_prior', 250.0, 'Prior standard deviation of each spin component', 'rad/s', 1, 5000),
    ('measured_spin_topic', '', 'geometry_msgs/Vector3Stamped topic of a measured spin '
     '(rad/s, table frame, e.g. from a marked ball) fused into the track; empty: none'),
    ('measured_spin_sigma', 10.0, 'Standard deviation of each measured spin component',
     'rad/s', 0.01, 1000),
    ('confirm_updates', 3, 'Filter updates before a track is published', '', 1, 100),
    ('max_coast', 0.06, 'Time without a measurement that ends a track', 's', 0.001, 5),
    ('camera_timeout', 1.0, 'Time without frames after which a camera is reported lost', 's',
     0.05, 60),
    ('reopen_interval', 1.0, 'Time between attempts to reopen a lost V4L2 device', 's',
     0.05, 60),
    ('device_width', 640, 'V4L2 frame width', 'pixels', 16, 8192),
    ('device_height', 480, 'V4L2 frame height', 'pixels', 16, 8192),
    ('device_fourcc', 'MJPG', 'V4L2 pixel format (FOURCC, e.g. MJPG or YUYV)'),
    ('device_exposure', -1.0, 'V4L2 exposure (driver units; negative: automatic)', '',
     -1, 100000),
    ('wait_for_subscribers', 1, 'video files: start reading once /ball/state has this many '
     'subscriptions (the first ball is not lost to a consumer still starting); 0: at once', '',
     0, 100),
    ('publish_clock', False, 'publish the time of the frame being processed on /clock, so '
     "that nodes with use_sim_time run on the recording's time (video files; image topics "
     'replayed without --clock)'),
))


def ball_state_message(est, t_ref, frame_id):
    """tt_msgs/BallState of a :class:`tt_perception.pipeline.BallEstimate` whose time is
    ``est.t`` s after the whole second ``t_ref`` (s)."""
    msg = BallState()
    ns = int(t_ref) * 1_000_000_000 + int(round(est.t * 1e9))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    msg.header.frame_id = frame_id
    s = est.state
    set_xyz(msg.position, s[:3])
    set_xyz(msg.velocity, s[3:6])
    set_xyz(msg.spin, s[6:9])
    msg.covariance = [float(v) for v in est.covariance.ravel()]
    msg.track_id = int(est.track_id)
    return msg


class PerceptionNode(Node):
    """Cameras in, /ball/state out (see the module docstring)."""

    def __init__(self, **kwargs):
        super().__init__('perception_node', **kwargs)
        self.p = Parameters(self, PARAMETERS)
        self.publisher = self.create_publisher(BallState, STATE_TOPIC, qos_profile_sensor_data)
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.clock_pub = None
        self.clock_msg = ClockMsg()
        self.last_clock_ns = None
        if self.p.publish_clock:
            # Best effort, depth 1: the QoS of the subscription of rclpy's time source.
            self.clock_pub = self.create_publisher(ClockMsg, '/clock', QoSProfile(
                depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.frames_received = 0
        self.states_published = 0
        self.spin_measurements_used = 0
        self.pipeline = None
        self.rig = None
        self._t_ref = None
        self._stop = threading.Event()
        self._queue = queue.Queue(maxsize=64)
        self._threads = []
        self._last_frame = {}
        self._lost = set()
        self._ended = set()           # cameras whose video files have ended
        self._disabled = set()
        self._warned = set()
        self._setup()

    def _p(self, name):
        return self.p[name]

    def _setup(self):
        rig_file = self._p('rig_file')
        if not rig_file:
            self.get_logger().error('parameter rig_file is empty: no cameras, no state')
            return
        try:
            rig = load_rig(rig_file, min_cameras=2)
        except CalibrationError as exc:
            self.get_logger().error(f'{exc}; no state will be published')
            return
        try:
            params = load_model(self._p('model_file') or None)
        except Exception as exc:       # the model loader's own errors (file, YAML, values)
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self.get_logger().error(f'model_file {self._p("model_file")}: {first}; no state '
                                    'will be published')
            return
        colour = self._p('ball_colour')
        detector = DetectorConfig(
            diff_threshold=self._p('diff_threshold'), min_area=self._p('min_area'),
            max_area=self._p('max_area'), max_width=self._p('max_width'), colour=colour,
            roi_half_size=self._p('roi_half_size'))
        filt = FilterConfig(accel_noise=self._p('accel_noise'), spin_prior=self._p('spin_prior'))
        tracker = TrackerConfig(confirm_updates=self._p('confirm_updates'),
                                max_coast=self._p('max_coast'),
                                pixel_sigma=self._p('pixel_sigma'),
                                max_reprojection=self._p('max_reprojection'))
        self.rig = rig
        self.pipeline = Pipeline(rig, params, detector, filt, tracker)
        files = []
        for k, cam in enumerate(rig.cameras):
            kind = source_kind(cam.source)
            if kind == 'topic':
                self.create_subscription(Image, cam.source,
                                         lambda msg, k=k: self._on_image(k, msg),
                                         qos_profile_sensor_data)
                self.create_subscription(CameraInfo, camera_info_topic(cam.source),
                                         lambda msg, k=k: self._on_info(k, msg),
                                         qos_profile_sensor_data)
            elif kind == 'v4l2':
                self._threads.append(threading.Thread(target=self._read_device, args=(k,),
                                                      daemon=True))
            else:
                files.append(k)
            self._last_frame[k] = time.monotonic()
        if files:
            self._threads.append(threading.Thread(target=self._read_files, args=(files,),
                                                  daemon=True))
        spin_topic = self._p('measured_spin_topic')
        if spin_topic:
            self.create_subscription(Vector3Stamped, spin_topic, self._on_spin,
                                     qos_profile_sensor_data)
        if self._threads:
            # On the steady clock: with use_sim_time a ROS-time timer would wait for /clock
            # (which this node may itself be the source of) to drain the frames.
            self.create_timer(0.002, self._drain, clock=self.steady)
        self.create_timer(0.25, self._watch_cameras)
        for thread in self._threads:
            thread.start()
        names = ', '.join(f'{c.name} ({c.source})' for c in rig.cameras)
        self.get_logger().info(f'rig {rig.path}: {names}; publishing {STATE_TOPIC}')

    # --- frames in ---------------------------------------------------------------------

    def _on_info(self, k, msg):
        cam = self.rig.cameras[k]
        fx, fy = msg.k[0], msg.k[4]
        size_ok = (msg.width, msg.height) == (cam.width, cam.height)
        focal_ok = fx <= 0 or abs(fx - cam.K[0, 0]) <= 0.02 * cam.K[0, 0] and \
            abs(fy - cam.K[1, 1]) <= 0.02 * cam.K[1, 1]
        if not (size_ok and focal_ok):
            if k not in self._disabled:
                self.get_logger().error(
                    f'camera {cam.name}: camera_info ({msg.width}x{msg.height}, fx {fx:.1f}) '
                    f'disagrees with its calibration ({cam.width}x{cam.height}, fx '
                    f'{cam.K[0, 0]:.1f}); its frames are ignored')
            self._disabled.add(k)
        elif k in self._disabled:
            self._disabled.discard(k)
            self.get_logger().info(f'camera {cam.name}: camera_info agrees again')

    def _on_image(self, k, msg):
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        try:
            frame = image_to_bgr(msg.encoding, msg.height, msg.width, msg.step, msg.data)
        except ValueError as exc:
            self._warn_once(('encoding', k), f'camera {self.rig.cameras[k].name}: {exc}')
            frame = None
        self._process(k, stamp if stamp > 0 else time.time(), frame)

    def _on_spin(self, msg):
        """A measured spin: fused into the running track (if its time is near it)."""
        if self.pipeline is None or self._t_ref is None:
            return
        t = msg.header.stamp.sec - self._t_ref + 1e-9 * msg.header.stamp.nanosec
        w = (msg.vector.x, msg.vector.y, msg.vector.z)
        if not all(math.isfinite(v) for v in w):
            self._warn_once('spin', f'measured spin {w} is not finite: ignored')
            return
        var = self._p('measured_spin_sigma') ** 2
        if self.pipeline.tracker.measure_spin(t, np.array(w), np.eye(3) * var):
            self.spin_measurements_used += 1

    def _put(self, k, t, frame, wait=False):
        """Queue a frame for processing; a live camera's frame is dropped when processing
        falls behind, a file's (``wait``) waits for room."""
        while not self._stop.is_set():
            try:
                self._queue.put((k, t, frame), timeout=0.1)
                return
            except queue.Full:
                if not wait:
                    self._warn_once(('queue', k), f'camera {self.rig.cameras[k].name}: '
                                    'processing falls behind, frames dropped')
                    return

    def _read_device(self, k):
        """One V4L2 camera: frames into the queue; reopened while it is away."""
        cam = self.rig.cameras[k]
        exposure = self._p('device_exposure')
        src = V4L2Source(cam.source, width=self._p('device_width'),
                         height=self._p('device_height'), fps=self.rig.fps,
                         fourcc=self._p('device_fourcc'),
                         exposure=exposure if exposure >= 0 else None,
                         reopen_interval=self._p('reopen_interval'))
        status = ''
        while not self._stop.is_set():
            t, frame = src.read()          # opens, and reopens a lost device, itself
            if src.status != status:
                status = src.status
                self.get_logger().warning(f'camera {cam.name}: {status}')
            if frame is None:
                self._stop.wait(0.01)
                continue
            self._put(k, t, frame)
        src.close()

    def _read_files(self, ks):
        """The video-file cameras, frame by frame together, paced at the rig's fps, once
        ``wait_for_subscribers`` subscriptions listen to the states (a video does not wait
        for a late consumer as a live camera would not)."""
        want = self._p('wait_for_subscribers')
        if self.publisher.get_subscription_count() < want:
            self.get_logger().info(f'video files: waiting for {want} subscription(s) on '
                                   f'{STATE_TOPIC}')
            while (self.publisher.get_subscription_count() < want
                   and not self._stop.wait(SUBSCRIBER_POLL_S)):
                pass
        start = time.monotonic()
        try:
            for t, k, frame in file_frames(self.rig, ks):
                if self._stop.wait(max(0.0, start + t - time.monotonic())):
                    break
                self._put(k, t, frame, wait=True)
        except OSError as exc:
            self.get_logger().error(str(exc))
        self._ended.update(ks)
        self._put(None, None, None, wait=True)     # logged once the frames before are done

    def _drain(self):
        while True:
            try:
                k, t, frame = self._queue.get_nowait()
            except queue.Empty:
                return
            if k is None:
                self.get_logger().info(f'end of the video files: {self.frames_received} '
                                       f'frames, {self.states_published} states')
                continue
            self._process(k, t, frame)

    # --- processing and output ---------------------------------------------------------

    def _process(self, k, stamp, frame):
        if self.pipeline is None:
            return
        self.frames_received += 1
        self._last_frame[k] = time.monotonic()
        if k in self._lost:
            self._lost.discard(k)
            self.get_logger().info(f'camera {self.rig.cameras[k].name}: frames again')
        if k in self._disabled:
            frame = None
        if self._t_ref is None:
            self._t_ref = math.floor(stamp)   # keeps sub-microsecond resolution in float64
        if self.clock_pub is not None:
            self._publish_clock(stamp)
        estimates = self.pipeline.process(stamp - self._t_ref, k, frame)
        if self.pipeline.last_error and k not in self._disabled:
            self._warn_once(('frame', self.pipeline.last_error), self.pipeline.last_error)
        for est in estimates:
            self.publisher.publish(ball_state_message(est, self._t_ref, self.rig.frame_id))
            self.states_published += 1

    def _publish_clock(self, stamp):
        """/clock at the frame time ``stamp`` (s), before the states of the frame; never back."""
        ns = int(round(stamp * 1e9))
        if self.last_clock_ns is not None and ns <= self.last_clock_ns:
            return
        self.last_clock_ns = ns
        set_time(self.clock_msg.clock, ns)
        self.clock_pub.publish(self.clock_msg)

    def _watch_cameras(self):
        now = time.monotonic()
        timeout = self._p('camera_timeout')
        for k, last in list(self._last_frame.items()):
            if (now - last > timeout and k not in self._lost and k not in self._ended
                    and self.frames_received):
                self._lost.add(k)
                cam = self.rig.cameras[k]
                self.get_logger().warning(f'camera {cam.name}: no frame for {timeout:.2f} s '
                                          f'from {cam.source}; waiting for it to come back')

    def _warn_once(self, key, text):
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    def destroy_node(self):
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        return super().destroy_node()


def main(args=None):
    run_node(PerceptionNode, args, name='perception_node')


if __name__ == '__main__':
    main()
