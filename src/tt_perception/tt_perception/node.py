"""perception_node: ball state from the rig's cameras, published on /ball/state.

ROS glue only (the math is in the pure modules). Each camera of the rig file comes from its
``source``: an image topic (sensor_msgs/Image on the source, or sensor_msgs/CompressedImage,
JPEG or PNG, on one ending in ``/compressed`` as image_transport names it; CameraInfo on the
sibling ``camera_info`` topic; sensor-data QoS), a V4L2 device or a video file paced at the
rig's fps as a camera (:mod:`tt_perception.camstream`: a reader thread per camera, a
bounded queue to one processing thread, every lost frame counted; times are video times, or
the wall clock with ``video_clock: wall``; ``publish_clock`` publishes the frame times on
/clock, so that nodes with ``use_sim_time`` share them). Every frame goes through
:class:`tt_perception.pipeline.Pipeline`; each estimate is published as tt_msgs/BallState
stamped with the exposure time of the camera-0 frame it derives from (the image header
stamp), 9x9 covariance row-major (position, velocity, spin).

Bad input never produces a state: a missing or invalid rig file is logged and the node stays
idle; a CameraInfo that disagrees with the calibration disables that camera with an error; a
frame of the wrong size or encoding is dropped with a warning; a camera that stops delivering
is reported (and a device reopened) while the node keeps running, an image topic that never
delivers too; a live camera whose stamps show another rate than the rig's ``fps`` (which
tracking uses) is named once.
"""

import contextlib
import dataclasses
import gc
import math
import os
import re
import sys
import threading
import time

import cv2
from geometry_msgs.msg import Vector3Stamped
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from tt_prediction.ball import load_model
from tt_prediction.identify.blas import blas_threads
from tt_ros.diagnostics import OK, WARN, percentile_values, report_status
from tt_ros.errors import one_line_reason
from tt_ros.executor import KERNELS_LOADING, StartupError, run_node, said_if_slow
from tt_ros.messages import set_time, set_xyz
from tt_ros.names import name_error
from tt_ros.parameters import Param, Parameters

from tt_msgs.msg import BallState

from .camera import CalibrationError, load_rig
from .camstream import (
    END,
    STAGE_WINDOW,
    CameraReader,
    DropCounter,
    Frame,
    FrameQueue,
    LatencyWindow,
    MonotonicClock,
    PacedVideoSource,
    open_v4l2,
    warm_up,
)
from .detect import (
    EXPOSURE_RANGE,
    IMAGE_BLUR_RANGE,
    NEAREST_BALL_M,
    RESPONSE_GAMMA_RANGE,
    DetectorConfig,
)
from .pipeline import PERCEPTION_FILTER, Pipeline, TrackerConfig
from .sources import (
    FrameRateCheck,
    camera_info_topic,
    device_error,
    file_source_path,
    file_sources_error,
    is_compressed_topic,
    message_to_bgr,
    source_kind,
)

STATE_TOPIC = 'ball/state'
"""The ball states' topic, relative to the node's namespace (/ball/state in the root one,
the name of tt-perceive's bags)."""
CAMERAS_DIAGNOSTIC = 'perception_node: cameras'
"""Name of the status on /diagnostics with the counts of the in-process cameras (frames read,
dropped and processed, latency, ``cameras_ended``, ``video_start_wall_s``), of the node in
the root namespace under its own name (``robot1/perception_node: cameras`` in /robot1)."""
CAMERA_BUFFERS = 8
"""Driver buffers of a camera (V4L2 CAP_PROP_BUFFERSIZE, 53 ms at 150 fps; a paced video file
emulates them): how long a camera thread may stall before frames are lost."""
FRESH_WAIT = 0.5
"""While no confirmed track runs, a camera thread waits up to this many frame periods for
the processing thread to have taken every running camera's frame before its own, so that a
track just started fits the ball in its next frames to the outline it predicts (a
frame detected before its track started has only its blob's centre, which leans toward the
lit side: a start that took such frames was 25 mm and 3 m/s off, an orange ball in synth's
hall at 640x480). A confirmed track's window and outline are predicted along its flight to the
frame's time (Tracker.predicted_motion), bounce included, and need no wait."""
QUIET_START_S = 10.0
"""While no camera has given a frame, an image topic is named as silent only after this
long (s; camera_timeout once frames come): its driver or a player may start after the
node."""
GIL_SWITCH_S = 5e-4
"""The interpreter's thread switch interval while cameras are read in-process, s (Python's
default 5 ms)."""


# Read once at start (the rig and the pipeline are built from them): read-only.
PARAMETERS = tuple(Param(*spec, read_only=True) for spec in (
    ('rig_file', '', 'Rig file (DESIGN.md): camera poses, camera_info files and sources'),
    ('model_file', '', 'Ball model YAML written by tt-identify (empty: nominal model)'),
    ('ball_colour', DetectorConfig.colour, 'Ball colour', '', None, None,
     ('white', 'orange', 'any')),
    ('diff_threshold', DetectorConfig.diff_threshold,
     'Grey-level change against the background of a ball pixel', '', 2, 200),
    ('colour_change_threshold', DetectorConfig.colour_change_threshold,
     'Change of one colour channel against the background (some channel not darker) of '
     'the pixels of a ball that fewer than min_area pixels changed in grey touch', '', 2,
     255),
    ('min_area', DetectorConfig.min_area, 'Smallest ball blob', 'pixels', 1, 10000),
    ('max_area', DetectorConfig.max_area, 'Largest ball blob (near, motion-blurred); 0: '
     "max_width's square", 'pixels', 0, 1000000),
    ('max_width', DetectorConfig.max_width, 'Largest ball diameter in the image; 0: a ball '
     f'{NEAREST_BALL_M:g} m from each camera, by its focal length (30 px at 554 px)', 'pixels',
     0, 1000),
    ('roi_half_size', DetectorConfig.roi_half_size,
     'Half size of the search window around the predicted ball; 0: 4/3 of max_width',
     'pixels', 0, 2000),
    ('exposure', DetectorConfig.exposure,
     'Exposure time of the cameras (the motion blur of the ball); tt-perceive prints each '
     "camera's, estimated from a recording", 's', *EXPOSURE_RANGE),
    ('response_gamma', DetectorConfig.response_gamma,
     "Cameras' response: pixel = 255 (light / full)^(1/gamma); 1 linear, about 2.2 for "
     'sRGB-like webcams', '', *RESPONSE_GAMMA_RANGE),
    ('curvature_weight', DetectorConfig.curvature_weight,
     "Penalty of the outline fit on the ball's brightness curving beyond a linear shading "
     '(0: a free quadratic, for a single compact light with no ambient)', '', 0.0, 100.0),
    ('inside_huber', DetectorConfig.inside_huber,
     "Threshold of the Huber weights of the pixels inside the ball in the outline fit's refit, "
     "in units of the fit's residual scale (a specular highlight counts less); 0: every pixel "
     'alike', '', 0.0, 100.0),
    ('image_blur', DetectorConfig.image_blur,
     "The cameras' own blur (demosaicing, JPEG, lens), a Gaussian standard deviation; 0.6: "
     "a Bayer colour camera's demosaicing; 0: sharp; tt-perceive prints each camera's, "
     'estimated from a recording', 'pixels', *IMAGE_BLUR_RANGE),
    ('encoded_blur', DetectorConfig.encoded_blur,
     "The cameras' blur of their pixel values after the response (JPEG's), a Gaussian "
     'standard deviation, used when response_gamma is not 1; 0.5: JPEG q30; 0: frames not '
     'compressed', 'pixels', *IMAGE_BLUR_RANGE),
    ('light_from_above', DetectorConfig.light_from_above,
     "The lights are above the table (the ball's top is its lit side): of the outline fits "
     'from several starts, one lit from below is kept only when all are; false: any '
     'lighting'),
    ('pixel_sigma', TrackerConfig.pixel_sigma, 'Standard deviation of a detected centre',
     'pixels', 0.01, 10),
    ('max_reprojection', TrackerConfig.max_reprojection,
     'Largest reprojection error of a triangulated ball', 'pixels', 0.1, 50),
    ('accel_noise', PERCEPTION_FILTER.accel_noise, 'Unmodelled acceleration of the filter (of '
     'a ball at rest when accel_noise_speed is set)', 'm/s^2/sqrt(Hz)', 0.0, 100),
    ('accel_noise_speed', PERCEPTION_FILTER.accel_noise_speed, 'Speed at which the unmodelled '
     "acceleration's aerodynamic part (growing as |v|^2) equals accel_noise; 0: the same at "
     'every speed (tt-predict --tracks learns accel_noise with 3.0 and writes both)', 'm/s',
     0.0, 100),
    ('bounce_velocity_noise', PERCEPTION_FILTER.bounce_velocity_noise, 'Standard deviation '
     'added to each velocity component at a bounce, for what the rebound model leaves out '
     '(tt-predict --tracks learns it from the rebounds it has seen)', 'm/s', 0.0, 10),
    ('spin_prior', PERCEPTION_FILTER.spin_prior, 'Prior standard deviation of the top/back '
     "spin (about the horizontal axis across the velocity at a track's start), and of every "
     'spin component unless spin_prior_side or spin_prior_along is set', 'rad/s', 1, 5000),
    ('spin_prior_side', 0.0, 'Prior standard deviation of the side spin (about the axis across '
     'the velocity in the vertical plane); 0: spin_prior', 'rad/s', 0, 5000),
    ('spin_prior_along', 0.0, 'Prior standard deviation of the spin along the velocity (which '
     'flight cannot show); 0: spin_prior', 'rad/s', 0, 5000),
    ('spin_prior_mean', list(PERCEPTION_FILTER.spin_prior_mean), 'Prior mean of the spin on '
     "the axes top/back (topspin positive), side, along the velocity at a track's start (as "
     'tt-predict --tracks learns it)', 'rad/s', -5000, 5000, (), 3),
    ('spin_outlier_prior', PERCEPTION_FILTER.spin_outlier_prior, 'Standard deviation of '
     "each spin component (mean 0) of a ball whose spin is not the spin prior's population "
     '(a rare strongly spun ball among slow ones)', 'rad/s', 1, 5000),
    ('spin_outlier_rate', PERCEPTION_FILTER.spin_outlier_rate, 'Prior probability of such a '
     'ball: where the spin prior is tighter across the velocity than spin_outlier_prior, a '
     'second filter with that prior runs until the bounce and its state is used while the '
     'data make it the more probable; 0: never', '', 0.0, 0.5),
    ('spin_outlier_wait', PERCEPTION_FILTER.spin_outlier_wait, "Time from a track's start "
     "before the second filter's state may be used", 's', 0.0, 1.0),
    ('measured_spin_topic', '', 'geometry_msgs/Vector3Stamped topic of a measured spin '
     '(rad/s, table frame, e.g. from a marked ball) fused into the track; empty: none'),
    ('measured_spin_sigma', 10.0, 'Standard deviation of each measured spin component',
     'rad/s', 0.01, 1000),
    ('confirm_updates', TrackerConfig.confirm_updates,
     'Filter updates before a track is published', '', 1, 100),
    ('unsure_updates', TrackerConfig.unsure_updates, 'Updates beyond confirm_updates after '
     "which a track no camera was sure of the ball's colour in (a far orange ball JPEG washed "
     'out, or a grey thing) ends unpublished', '', 0, 100),
    ('backfill', False, "On a track's confirmation also publish the states of its frames "
     'before it (its seed, its start and the updates before confirmation, carried back from '
     'the confirming estimate; 4 frames, up to 27 ms late at 150 fps, unless it waited for '
     "a camera sure of the ball's colour), so that /ball/state covers each "
     'flight from its first frame pair (a recording); off: every state published is that of '
     'the newest frame, which is what the robot needs'),
    ('max_coast', TrackerConfig.max_coast, 'Time without a measurement that ends a track', 's',
     0.001, 5),
    ('camera_timeout', 1.0, 'Time without frames after which a camera is reported lost', 's',
     0.05, 60),
    ('reopen_interval', 1.0, 'Time between attempts to reopen a lost V4L2 device', 's',
     0.05, 60),
    ('device_width', 0, "V4L2 frame width (0: each camera's calibration's)", 'pixels', 0,
     8192),
    ('device_height', 0, "V4L2 frame height (0: each camera's calibration's)", 'pixels', 0,
     8192),
    ('device_fourcc', 'MJPG', "V4L2 pixel format (FOURCC: 4 characters, e.g. MJPG or YUYV; "
     "empty: the driver's)"),
    ('device_exposure', -1.0, 'V4L2 exposure (driver units; negative: automatic)', '',
     -1, 100000),
    ('video_clock', 'video', "Stamps of video-file frames: 'video' (s from the first frame) or "
     "'wall' (the wall-clock time the paced frame is exposed, as a live camera's; needs "
     'video_rate 1)', '', None,
     None, ('video', 'wall')),
    ('frame_queue', 8, 'Frames queued per camera for processing; beyond, the oldest is '
     'dropped (counted)', '', 2, 1000),
    ('video_rate', 1.0, 'Playback speed of video files: 1 = real time, as cameras (frames lost '
     'when processing falls behind, counted); 0 = each frame once the one before is taken, '
     'none lost (offline, tests)', '', 0.0, 100.0),
    ('wait_for_subscribers', 0, 'Video files start once /ball/state has this many '
     'subscriptions', '', 0, 100),
    ('publish_clock', False, 'publish the time of the frame being processed on /clock (before '
     "its states), so that nodes with use_sim_time run on the recording's time (video files "
     "with video_clock 'video'; image topics replayed without --clock)"),
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


def check_parameters(values):
    """perception_node's cross-parameter rule on all its ``values``: the one-line reason they
    are refused, or None (min_area above max_area let no blob pass: 0 states, no word)."""
    if values['max_area'] and values['min_area'] > values['max_area']:
        return (f"min_area ({values['min_area']} pixels) must not exceed max_area "
                f"({values['max_area']} pixels)")
    return None


class PerceptionNode(Node):
    """Cameras in, /ball/state out (see the module docstring). ``monotonic``: the clock (s)
    of the camera watchdog, which reports a camera without frames for ``camera_timeout``."""

    def __init__(self, *, monotonic=time.monotonic, **kwargs):
        super().__init__('perception_node', **kwargs)
        self._monotonic = monotonic
        self.p = Parameters(self, PARAMETERS, check=check_parameters)
        self.publisher = self.create_publisher(BallState, STATE_TOPIC, qos_profile_sensor_data)
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
        self._lock = threading.Lock()       # the pipeline: processing thread and callbacks
        self._readers = []
        self._worker = None
        self._files = []
        self._video_start = None            # wall-clock time of video time 0, s
        self._wall_stamps = False
        self.frames_queue = None
        self.drops = None
        self.latency = LatencyWindow()
        self.process_time = LatencyWindow(STAGE_WINDOW)   # a frame of the cameras, processed
        self._snapshot = None               # the track, for the camera threads' detection
        self._processed = threading.Condition()     # ... and when it was taken (FRESH_WAIT)
        self._processed_t = {}              # camera -> stamp of its latest frame processed, s
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._last_frame = {}
        self._image_types = {}      # camera index -> the message type its image topic needs
        self._colour_known = set()  # cameras whose frames are known to be grey or not
        self._lost = set()
        self._delivered = set()       # cameras that delivered a frame (read, or a read error)
        self._rates = FrameRateCheck([], 0.0, ())     # the live cameras' rates (the rig's)
        self._devices = set()         # cameras that are V4L2 devices
        self._ended = set()           # cameras whose video files have ended
        self._disabled = set()
        self._warned = set()
        self._exit = contextlib.ExitStack()     # undone in destroy_node
        self._setup()

    def _p(self, name):
        return self.p[name]

    def _setup(self):
        """The rig, model and sources; StartupError (one line, exit 2, as the other nodes) for
        an empty or bad rig_file, a bad model_file or a topic name no ROS topic can have."""
        rig_file = self._p('rig_file')
        if not rig_file:
            raise StartupError('rig_file is empty: give the rig (-p rig_file:=RIG.yaml, or '
                               'bringup --rig RIG.yaml)')
        try:
            rig = load_rig(rig_file, min_cameras=2, need_source=True)
        except CalibrationError as exc:
            raise StartupError(str(exc)) from None
        try:
            params = load_model(self._p('model_file') or None)
        except Exception as exc:       # the model loader's own errors (file, YAML, values)
            raise StartupError(f'model_file: {one_line_reason(exc)}') from None
        kinds = [source_kind(cam.source, os.path.dirname(rig.path)) for cam in rig.cameras]
        for cam, kind in zip(rig.cameras, kinds, strict=True):
            if kind == 'topic':
                _check_topic(cam.source, f'rig {rig_file}: camera {cam.name}: source '
                             f'{cam.source!r} is no video file, image sequence or V4L2 device '
                             'and')
            error = device_error(cam.source) if kind == 'v4l2' else ''
            if error:
                raise StartupError(f'rig {rig_file}: camera {cam.name}: {error}')
        # Video files missing, unreadable, of another frame size, at different rates.
        notes = []
        error = file_sources_error(rig, notes)
        if error:
            raise StartupError(f'rig {rig_file}: {error}')
        for note in notes:
            self.get_logger().warning(f'rig {rig_file}: {note}')
        if self._p('measured_spin_topic'):
            _check_topic(self._p('measured_spin_topic'), 'measured_spin_topic')
        fourcc = self._p('device_fourcc')
        if fourcc and (len(fourcc) != 4 or not fourcc.isascii()):
            raise StartupError(f"device_fourcc '{fourcc}' is not 4 characters (e.g. MJPG, "
                               "YUYV; empty: the driver's format)")
        if (self._p('video_clock') == 'wall' and self._p('video_rate') != 1.0
                and 'file' in kinds):
            raise StartupError(f"video_clock 'wall' needs video_rate 1: at "
                               f"{self._p('video_rate'):g}x the wall clock would stretch the "
                               "ball's flight (video_clock 'video' keeps the video's time)")
        colour = self._p('ball_colour')
        detector = DetectorConfig(
            diff_threshold=self._p('diff_threshold'),
            colour_change_threshold=self._p('colour_change_threshold'),
            min_area=self._p('min_area'),
            max_area=self._p('max_area'), max_width=self._p('max_width'), colour=colour,
            roi_half_size=self._p('roi_half_size'), exposure=self._p('exposure'),
            response_gamma=self._p('response_gamma'),
            curvature_weight=self._p('curvature_weight'), image_blur=self._p('image_blur'),
            encoded_blur=self._p('encoded_blur'), inside_huber=self._p('inside_huber'),
            light_from_above=self._p('light_from_above'))
        filt = dataclasses.replace(PERCEPTION_FILTER, accel_noise=self._p('accel_noise'),
                                   accel_noise_speed=self._p('accel_noise_speed'),
                                   bounce_velocity_noise=self._p('bounce_velocity_noise'),
                                   spin_prior=self._p('spin_prior'),
                                   spin_prior_side=self._p('spin_prior_side') or None,
                                   spin_prior_along=self._p('spin_prior_along') or None,
                                   spin_prior_mean=tuple(self._p('spin_prior_mean')),
                                   spin_outlier_prior=self._p('spin_outlier_prior'),
                                   spin_outlier_rate=self._p('spin_outlier_rate'),
                                   spin_outlier_wait=self._p('spin_outlier_wait'))
        tracker = TrackerConfig(confirm_updates=self._p('confirm_updates'),
                                unsure_updates=self._p('unsure_updates'),
                                max_coast=self._p('max_coast'),
                                pixel_sigma=self._p('pixel_sigma'),
                                max_reprojection=self._p('max_reprojection'),
                                backfill=self._p('backfill'), backfill_after=0.0)
        self.rig = rig
        self.pipeline = Pipeline(rig, params, detector, filt, tracker)
        for cam, d in zip(rig.cameras, self.pipeline.detectors, strict=True):
            if d.config.min_area > d.config.max_area:
                raise StartupError(f"min_area ({d.config.min_area} pixels) must not exceed "
                                   f"camera {cam.name}'s max_area ({d.config.max_area} pixels, "
                                   'from its focal length)')
        with said_if_slow(self.get_logger(), KERNELS_LOADING):
            warm_up(params, filt, rig.fps)  # compiled kernels loaded before the first frame
        files, devices = [], []
        for k, (cam, kind) in enumerate(zip(rig.cameras, kinds, strict=True)):
            if kind == 'topic':
                msg_type = CompressedImage if is_compressed_topic(cam.source) else Image
                self._image_types[k] = f'sensor_msgs/msg/{msg_type.__name__}'
                self.create_subscription(msg_type, cam.source,
                                         lambda msg, k=k: self._on_image(k, msg),
                                         qos_profile_sensor_data)
                self.create_subscription(CameraInfo, camera_info_topic(cam.source),
                                         lambda msg, k=k: self._on_info(k, msg),
                                         qos_profile_sensor_data)
            elif kind == 'v4l2':
                devices.append(k)
            else:
                files.append(k)
            self._last_frame[k] = self._monotonic()
        # The live cameras are stamped by themselves, not by the rig's fps.
        self._rates = FrameRateCheck([c.name for c in rig.cameras], rig.fps,
                                     [k for k, kind in enumerate(kinds) if kind != 'file'])
        self.drops = DropCounter(len(rig.cameras))
        lossless = self._p('video_rate') == 0.0 and not devices
        self.frames_queue = FrameQueue(
            self._p('frame_queue'), self.drops, lossless=lossless, stop=self._stop,
            offsets=[c.time_offset or 0.0 for c in rig.cameras],
            max_lag=None if lossless else 3.0 / rig.fps, cameras=devices + files,
            min_gap=0.5 / rig.fps)
        self._wall_stamps = self._p('video_clock') == 'wall'
        self._devices = set(devices)
        if devices:
            self._t_ref = math.floor(time.time())     # V4L2 stamps are wall-clock times
        for k in devices:
            self._readers.append(self._device_reader(k))
        self._files = files
        spin_topic = self._p('measured_spin_topic')
        if spin_topic:
            self.create_subscription(Vector3Stamped, spin_topic, self._on_spin,
                                     qos_profile_sensor_data)
        if devices or files:
            self._worker = threading.Thread(target=self._work, daemon=True, name='perception')
            self._worker.start()
            report_status(self, 'cameras', self.rig.path, self._cameras_status)
        for reader in self._readers:
            reader.start()
        if files:
            self._said_waiting = False
            self._file_timer = self.create_timer(0.01, self._start_files, clock=self.steady)
        if devices:
            _freeze_garbage()       # video files: once they are open (_start_files)
        if devices or files:
            # One thread per OpenCV call and per BLAS product: the camera threads already use
            # the other core, and a call split over two threads waits for the slower one,
            # which on a busy machine may not be running at all.
            cv2.setNumThreads(1)
            # The processing thread waits for frames; each time one comes it needs the GIL
            # from a camera thread busy in Python, which by default keeps it up to 5 ms
            # (sys.getswitchinterval): at 300 frames/s the queue then fills although a core
            # is idle (camrate bench: exposure -> /ball/state p50 42 ms; 12 ms at 0.5 ms).
            sys.setswitchinterval(GIL_SWITCH_S)
            self._exit.enter_context(blas_threads(1))
        self.create_timer(0.25, self._watch_cameras)
        # An image topic as resolved (cam0/image_raw is /robot1/cam0/image_raw in /robot1).
        shown = [self.resolve_topic_name(c.source) if kind == 'topic' else c.source
                 for c, kind in zip(rig.cameras, kinds, strict=True)]
        names = ', '.join(f'{c.name} ({source})' for c, source in zip(rig.cameras, shown,
                                                                        strict=True))
        model = self._p('model_file') or 'nominal'
        self.get_logger().info(f'rig {rig.path}: {names}; publishing '
                               f'{self.publisher.topic_name}; model {model}')

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
            frame = message_to_bgr(msg)
        except ValueError as exc:
            # Once for each kind of problem (its sizes aside) of each camera.
            self._warn_once(('image', k, re.sub(r'[0-9]+', 'N', str(exc))),
                            f'camera {self.rig.cameras[k].name}: {exc}')
            frame = None
        if stamp <= 0:
            self._warn_once(('zero stamp', k),
                            f'camera {self.rig.cameras[k].name}: its images are stamped 0 (the '
                            'driver left header.stamp unset): their arrival times are taken, '
                            'late by the transport and uneven; have the driver stamp them')
            stamp = time.time()
        self._process(k, stamp, frame)

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
        with self._lock:
            used = self.pipeline.tracker.measure_spin(t, np.array(w), np.eye(3) * var)
        if used:
            self.spin_measurements_used += 1

    def _device_reader(self, k):
        """The reader thread of V4L2 camera ``k`` (opened, and reopened, by the thread)."""
        cam = self.rig.cameras[k]
        exposure = self._p('device_exposure')
        # The size asked: the parameters', else the camera's calibration's (its frames' size).
        width, height = self._p('device_width'), self._p('device_height')
        source = open_v4l2(cam.source, width=width or cam.width, height=height or cam.height,
                           fps=self.rig.fps, fourcc=self._p('device_fourcc'),
                           exposure=exposure if exposure >= 0 else None,
                           reopen_interval=self._p('reopen_interval'), buffers=CAMERA_BUFFERS)
        source.stop = self._stop
        return CameraReader(k, source, self.frames_queue, self.drops,
                            on_status=lambda k, text: self._device_status(k, source.source,
                                                                          text),
                            on_error=self._reader_error, detect=self._detect,
                            ready=self._wait_for_track, after=self._after_detect)

    def _device_status(self, k, source, text):
        """V4L2 camera ``k``'s new status ``text`` (from its thread): opened at INFO, with
        what its driver gives where it is not what was asked (once each), else a warning."""
        name = self.rig.cameras[k].name
        if text.endswith(('opened', 'reopened')):
            self.get_logger().info(f'camera {name}: {text}')
            if source.mismatch:
                self._warn_once(('driver', k, source.mismatch),
                                f'camera {name}: {source.mismatch}')
            if source.driver_fps:
                # Its rate known (and said if not the rig's): not judged again from the
                # stamps of the frames processed, of which the queue may drop some under load.
                with self._lock:
                    self._rates.drop(k)
        else:
            self.get_logger().warning(f'camera {name}: {text}')

    def _start_files(self):
        """Start the video files together (frame n of each at the same instant), once
        ``wait_for_subscribers`` subscriptions of /ball/state are there."""
        topic = self.publisher.topic_name
        have, want = self.count_subscribers(topic), self._p('wait_for_subscribers')
        if have < want:
            if not self._said_waiting:
                self._said_waiting = True
                self.get_logger().info(
                    f'video files wait for {want} subscription(s) of {topic} '
                    f'({have} now; parameter wait_for_subscribers)')
            return
        self._file_timer.cancel()
        fps = self.rig.fps
        sources = []
        for k in self._files:
            cam = self.rig.cameras[k]
            try:
                source = PacedVideoSource(file_source_path(self.rig, cam), fps,
                                          buffers=CAMERA_BUFFERS, stop=self._stop,
                                          rate=self._p('video_rate')).open()
                error, warning = source.disagreement(cam, fps)
                if warning:
                    self.get_logger().warning(f'camera {cam.name}: {warning}')
                if error:
                    source.close()
                    raise OSError(f'{error}: its frames are not used')
            except OSError as exc:
                self.get_logger().error(f'camera {cam.name}: {exc}')
                # Ended before its first frame: the other cameras are not held back for it.
                self.frames_queue.put(Frame(k, -1, float('nan'), None, kind=END))
                continue
            sources.append((k, source))
        # The files are open and out of the collector's way: frame 0 of every file 20 ms from
        # now, on the camera threads' clock. Set before the files were opened (and before a
        # full collection of up to 70 ms), the first frames came 20 ms late.
        _freeze_garbage()
        start = MonotonicClock.now() + 0.02
        self._video_start = time.time() + (start - MonotonicClock.now())
        readers = []
        for k, source in sources:
            source.start = start
            t0 = self._video_start if self._wall_stamps else 0.0
            if self._t_ref is None:
                self._t_ref = math.floor(t0)
            readers.append(CameraReader(k, source, self.frames_queue, self.drops,
                                        stamp=lambda n, t0=t0: t0 + n / fps,
                                        on_error=self._reader_error, detect=self._detect,
                                        ready=self._wait_for_track, after=self._after_detect))
        self._files = [r.camera for r in readers]
        self._readers += readers
        for reader in readers:
            reader.start()
        self.get_logger().info(f'video files started: video time 0 at wall time '
                               f'{self._video_start:.6f} s')

    def _wait_for_track(self, k, stamp):
        """Before camera ``k``'s detection of its frame stamped ``stamp`` (s), in its thread:
        while no confirmed track runs, wait until the processing thread has taken every
        running camera's frame before this instant, for up to :data:`FRESH_WAIT` frame
        periods."""
        snapshot = self._snapshot
        if snapshot is not None and snapshot[3]:
            return
        period = 1.0 / self.rig.fps
        running = [j for j in range(len(self.rig.cameras))
                   if j not in self._lost and j not in self._ended and j not in self._disabled]

        def taken():
            return all(self._processed_t.get(j, -math.inf) >= stamp - 1.5 * period
                       for j in running)

        with self._processed:
            self._processed.wait_for(taken, FRESH_WAIT * period)

    def _detect(self, k, stamp, image):
        """Camera ``k``'s ball detection, in its own thread (the search window from the
        track as the processing thread last left it, :meth:`_wait_for_track`); its background
        update waits for :meth:`_after_detect`."""
        return self.pipeline.detect(stamp - self._t_ref, k, image, self._snapshot, later=True)

    def _after_detect(self, k):
        """Camera ``k``'s background update, once its frame's detections are queued."""
        self.pipeline.update_background(k)

    def _reader_error(self, k, exc):
        self.get_logger().error(f'camera {self.rig.cameras[k].name}: {exc}')

    def _work(self):
        """The processing thread: frames of the camera threads, in arrival order."""
        while not self._stop.is_set():
            frame = self.frames_queue.get(timeout=0.1)
            if frame is None:
                continue
            if frame.kind == END:
                self._ended.add(frame.camera)
                if self._files and self._ended >= set(self._files):
                    self.get_logger().info(f'end of the video files: {self.work_summary()}')
                    for warning in (self.pipeline.colour_refused_warning(),
                                    self.pipeline.geometry_warning()):
                        if warning:
                            self.get_logger().warning(warning)
                continue
            # Exposure times on the wall clock: live stamps are; video times start at the
            # files' start.
            if frame.camera not in self._files or self._wall_stamps:
                base = 0.0
            else:
                base = self._video_start if self._p('video_rate') == 1.0 else None
            try:
                self._process(frame.camera, frame.t, frame.image, base, frame.detections)
            except Exception as exc:  # noqa: BLE001 - one bad frame must not stop the cameras
                self._warn_once(('worker', type(exc).__name__),
                                f'camera {self.rig.cameras[frame.camera].name}: frame not '
                                f'processed: {type(exc).__name__}: {exc}')

    def _cameras_status(self):
        """The status on /diagnostics: frames read and lost per camera, frame pairs lost,
        latency and the time of each stage (a camera's read and detection, the processing of a
        frame)."""
        lost, pairs = self.drops.snapshot()
        values = {'frame_pairs_dropped': pairs, 'frames_processed': self.frames_received,
                  'states_published': self.states_published,
                  'queue_high_water': self.frames_queue.high_water,
                  **_percentiles('latency', self.latency),
                  'latency_count': self.latency.count,
                  'cameras_ended': len(self._ended),
                  'video_start_wall_s': ('' if self._video_start is None
                                         else f'{self._video_start:.6f}')}
        for reader in self._readers:
            name = self.rig.cameras[reader.camera].name
            values[f'{name}_frames_read'] = reader.frames
            for stage, window in (('read', reader.read_time), ('detect', reader.detect_time)):
                values.update(_percentiles(f'{name}_{stage}', window))
        values.update(_percentiles('process', self.process_time))
        for k, cam in enumerate(self.rig.cameras):
            values[f'{cam.name}_frames_dropped'] = lost[k]
        return (OK if pairs == 0 else WARN), f'{pairs} frame pairs dropped', values

    # --- processing and output ---------------------------------------------------------

    def _process(self, k, stamp, frame, wall_base=None, detections=None):
        """Camera ``k``'s frame stamped ``stamp`` (s) through the pipeline; its states are
        published. ``wall_base`` (s): the stamp plus it is the wall-clock exposure time, for
        the exposure -> publication latency (frames of the camera threads)."""
        if self.pipeline is None:
            return
        start = time.perf_counter()
        with self._lock:
            self._process_locked(k, stamp, frame, wall_base, detections)
            self._snapshot = self.pipeline.tracker.snapshot()
        with self._processed:
            self._processed_t[k] = max(self._processed_t.get(k, -math.inf), stamp)
            self._processed.notify_all()
        if detections is not None:                  # a frame of the camera threads
            self.process_time.add(time.perf_counter() - start)

    def _process_locked(self, k, stamp, frame, wall_base, detections):
        self.frames_received += 1
        self._last_frame[k] = self._monotonic()
        refused = frame is None and detections is None    # an image message not read (said)
        again = k in self._delivered
        if not refused:
            self._delivered.add(k)
        if k in self._lost and not refused:
            self._lost.discard(k)
            self.get_logger().info(f'camera {self.rig.cameras[k].name}: '
                                   + ('frames again' if again else 'first frame'))
        if k in self._disabled:
            frame, detections = None, None
        if self._t_ref is None:
            self._t_ref = math.floor(stamp)   # keeps sub-microsecond resolution in float64
        if self.clock_pub is not None:
            self._publish_clock(stamp)
        estimates = self.pipeline.process(stamp - self._t_ref, k, frame, detections)
        if k not in self._colour_known and self.pipeline.detectors[k].colourless is not None:
            self._colour_known.add(k)           # known from a camera's first frame
            grey = self.pipeline.colour_warning()
            if grey:
                self._warn_once(('grey', grey), grey)
        if self.pipeline.last_error and k not in self._disabled and not refused:
            error = self.pipeline.last_error
            if k in self._devices and 'frames of another size' in error:
                error += ("; device_width and device_height set the size asked of the V4L2 "
                          "driver (0: the calibration's), or calibrate the camera at the "
                          'size it gives')
            self._warn_once(('frame', error), error)
        text = self._rates.add(k, stamp)
        if text:
            self.get_logger().warning(text)
        for est in estimates:
            self.publisher.publish(ball_state_message(est, self._t_ref, self.rig.frame_id))
            self.states_published += 1
            if wall_base is not None:
                self.latency.add(time.time() - (wall_base + self._t_ref + est.t))

    def _publish_clock(self, stamp):
        """/clock at the frame time ``stamp`` (s), before the states of the frame; never back."""
        ns = int(round(stamp * 1e9))
        if self.last_clock_ns is not None and ns <= self.last_clock_ns:
            return
        self.last_clock_ns = ns
        set_time(self.clock_msg.clock, ns)
        self.clock_pub.publish(self.clock_msg)

    def _watch_cameras(self):
        now = self._monotonic()
        timeout = self._p('camera_timeout')
        for k, last in list(self._last_frame.items()):
            # An image topic is waited for from the start (misspelt, in another namespace, or
            # only its compressed transport published, the node said nothing), for
            # QUIET_START_S while no camera has given a frame (a driver or player started
            # after the node: the demo's was named every time); the other cameras once a
            # frame has come (a device says why it gives none, video files may wait for
            # subscribers).
            limit = timeout if self.frames_received else max(timeout, QUIET_START_S)
            if (now - last > limit and k not in self._lost and k not in self._ended
                    and (self.frames_received or k in self._image_types)):
                self._lost.add(k)
                cam = self.rig.cameras[k]
                source = (self.resolve_topic_name(cam.source) if k in self._image_types
                          else cam.source)
                self.get_logger().warning(
                    f'camera {cam.name}: no frame for {limit:.2f} s from {source}; '
                    + ('waiting for it to come back' if k in self._delivered else
                       'no frame read from it yet, waiting for one' + self._topic_hint(k)))
            if now - last > timeout and k in self._image_types:
                self._check_image_type(k)

    def _topic_hint(self, k):
        """For image-topic camera ``k`` that never delivered: '' or the topic of the other
        transport (``.../compressed`` beside a raw name, or the reverse) that has publishers,
        as the source to give."""
        if k not in self._image_types:
            return ''
        name = self.resolve_topic_name(self.rig.cameras[k].source)
        other = (name.rstrip('/').rsplit('/', 1)[0] if is_compressed_topic(name)
                 else f'{name}/compressed')
        if not self.get_publishers_info_by_topic(other):
            return ''
        return f" ({other} has publishers: give it as the camera's source in the rig to read it)"

    def _check_image_type(self, k):
        """Warn (once for each set of types) when the publishers of camera ``k``'s silent image
        topic send another message type than the one it is read as: the two never connect,
        and the node waited without a word (an image_transport compressed topic under a raw
        name)."""
        cam = self.rig.cameras[k]
        name = self.resolve_topic_name(cam.source)
        types = tuple(sorted({p.topic_type for p in self.get_publishers_info_by_topic(name)}))
        wanted = self._image_types[k]
        if not types or wanted in types:
            return
        hint = ('a topic whose name ends in /compressed is read as CompressedImage, any other '
                'as Image' if 'sensor_msgs/msg/CompressedImage' in types + (wanted,) else
                'an image topic carries sensor_msgs/msg/Image or CompressedImage')
        self._warn_once(('image type', k, types),
                        f'camera {cam.name}: {name} carries {", ".join(types)}, not {wanted}, '
                        f"so no image of it arrives: {hint} (the rig's source)")

    def work_summary(self):
        """One line of what the node has done: frames, states, frame pairs dropped (at the
        end of the video files, and on exit)."""
        return (f'{self.frames_received} frames, {self.states_published} states, '
                f'{self.drops.pairs} frame pairs dropped')

    def _warn_once(self, key, text):
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    def stop_work(self):
        """Stop the camera readers and the processing thread and wait for them (2 s each):
        the states they still publish are counted before the exit line (5260 said of 5262
        received, a walk-through's)."""
        self._stop.set()
        for thread in [*self._readers, self._worker]:
            if thread is not None and thread.is_alive():
                thread.join(timeout=2.0)

    def destroy_node(self):
        self.stop_work()
        self._exit.close()
        return super().destroy_node()


def _freeze_garbage():
    """Collect, then keep every object alive now (ROS, numba, the rig, the open sources: they
    live as long as the node) out of the garbage collector's full passes, which would
    otherwise stall the camera path for tens of ms now and then."""
    gc.collect()
    gc.freeze()


def _percentiles(key, window):
    """/diagnostics values ``<key>_p50_ms`` and ``<key>_p99_ms`` of a :class:`LatencyWindow`."""
    return percentile_values(key, *window.percentiles_ms())


def _check_topic(name, what):
    """StartupError '<what> is not a valid topic name: <why>' for a name no topic can have."""
    error = name_error(name)
    if error:
        raise StartupError(f'{what} is not a valid topic name: {error}')


def _on_exit(node):
    node.stop_work()
    node.get_logger().info(node.work_summary())


def main(args=None):
    run_node(PerceptionNode, args, name='perception_node', parameters=PARAMETERS,
             on_exit=_on_exit)


if __name__ == '__main__':
    main()
