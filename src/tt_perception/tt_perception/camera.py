"""Calibrated pinhole cameras and the rig file (DESIGN.md, "Data formats").

A camera maps a point X (m, ``table`` frame) to its optical frame by X_cam = R X + t (z
forward, x right, y down) and then to pixels by the pinhole matrix K and OpenCV's
plumb-bob distortion (k1, k2, p1, p2, k3), or its rational model's 8 coefficients.
Intrinsics come from the ROS camera_info YAML (the format ``camera_calibration`` writes); the
rig file gives each camera's pose and source.
Every loading error is a :class:`CalibrationError` with a one-line message naming the file
and the field.
"""

import dataclasses
import io
import math
import os

import cv2
from numba import njit
import numpy as np
from tt_prediction.staged import replace_file
from tt_prediction.units import translation_error
from tt_ros.errors import one_line_reason
from tt_ros.yamlfile import load_yaml
import yaml

# OpenCV 5 takes the criteria in undistortPoints; OpenCV 4 has them in undistortPointsIter.
_undistort = getattr(cv2, 'undistortPointsIter', cv2.undistortPoints)
_EYE = np.eye(3)


class CalibrationError(ValueError):
    """A camera_info or rig file that is missing, unreadable or inconsistent."""


UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-9)
"""Iteration criteria of the undistortion: at most 20 iterations or a step below 1e-9."""
IN_FRONT_DEPTH = 1e-3
"""Least depth along a camera's axis of a point in front of it, m (:meth:`Camera.in_front`)."""
DISTORTION_SIZES = (4, 5, 8)
"""Numbers of distortion coefficients: plumb-bob without and with k3, rational polynomial."""
ROTATION_TOLERANCE = 1e-4
"""Largest entry of R R^T - I, and of det R - 1, of a rig pose's rotation."""


@dataclasses.dataclass
class Camera:
    """One calibrated camera: intrinsics, distortion and pose in the ``table`` frame."""

    name: str
    width: int
    height: int
    K: np.ndarray
    """3x3 camera matrix, pixels."""
    dist: np.ndarray
    """Distortion coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]) in OpenCV's order:
    plumb-bob (4 or 5) or rational polynomial (8)."""
    R: np.ndarray
    """3x3 rotation, table -> optical frame."""
    t: np.ndarray
    """Translation (3,), m: X_cam = R X_table + t."""
    source: str = ''
    time_offset: float | None = None
    """This camera's clock minus camera 0's, s (None: unknown); on camera 0, a delay of its
    own stamps (each camera's stamps less it are the middle of its exposure)."""
    readout_time: float = 0.0
    """A rolling shutter's readout, s: the time from the first row's exposure to the last's
    (0: a global shutter). The stamp (less ``time_offset``) is then the middle row's."""
    white_bgr: tuple = (1.0, 1.0, 1.0)
    """The colour (B, G, R) of a white surface in this camera's images, the largest 1: the
    light's colour as the camera's white balance leaves it (the ball's colour is judged
    against it)."""
    info_file: str = ''
    """The camera_info file as the rig names it (relative to the rig file)."""

    def __post_init__(self):
        self.K = np.asarray(self.K, dtype=float).reshape(3, 3)
        self.dist = np.asarray(self.dist, dtype=float).ravel()
        # C-ordered: the compiled kernels take them as they are (pipeline.ball_image).
        self.R = np.ascontiguousarray(np.asarray(self.R, dtype=float).reshape(3, 3))
        self.t = np.ascontiguousarray(np.asarray(self.t, dtype=float).ravel())
        if self.dist.size not in DISTORTION_SIZES:
            raise CalibrationError(f'camera {self.name}: {self.dist.size} distortion '
                                   'coefficients (4, 5 or 8: plumb_bob or rational_polynomial)')
        self.intrinsics = np.array([self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]])
        """(fx, fy, cx, cy), pixels (:func:`project_optical`)."""
        self.rational_dist = np.zeros(8)
        """:attr:`dist` as the rational model's 8 coefficients (zeros added)."""
        self.rational_dist[:self.dist.size] = self.dist
        self._rvec = cv2.Rodrigues(self.R)[0]
        self.centre = -self.R.T @ self.t
        """Optical centre in the table frame, m."""

    @property
    def focal(self):
        """Mean focal length, pixels."""
        return 0.5 * (self.K[0, 0] + self.K[1, 1])

    def to_camera(self, points):
        """Table-frame points (n, 3) -> optical-frame points (n, 3), m."""
        return np.atleast_2d(points) @ self.R.T + self.t

    def project(self, points):
        """Table-frame points (n, 3), m -> distorted pixel coordinates (n, 2)."""
        pts = np.ascontiguousarray(np.atleast_2d(points), dtype=float).reshape(-1, 1, 3)
        px, _ = cv2.projectPoints(pts, self._rvec, self.t, self.K, self.dist)
        return px.reshape(-1, 2)

    def normalise(self, pixels):
        """Distorted pixels (n, 2) -> undistorted normalised coordinates (n, 2) (x/z, y/z).

        Uses OpenCV's iterative ``undistortPoints`` with the explicit
        :data:`UNDISTORT_CRITERIA` (``undistortPointsIter`` in OpenCV 4).
        """
        pts = np.ascontiguousarray(np.atleast_2d(pixels), dtype=float).reshape(-1, 1, 2)
        out = _undistort(pts, self.K, self.dist, R=_EYE, P=_EYE, criteria=UNDISTORT_CRITERIA)
        return out.reshape(-1, 2)

    def row_delay(self, v):
        """When image row ``v`` (pixels, 0 at the top; array or number) was exposed, s after
        the frame's stamp less ``time_offset`` (the middle row's time): a rolling shutter's
        rows in turn over :attr:`readout_time`; 0 for a global shutter."""
        return (np.asarray(v, dtype=float) / (self.height - 1) - 0.5) * self.readout_time

    def in_front(self, points):
        """True where the table-frame points (n, 3) lie in front of the camera."""
        return self.to_camera(points)[:, 2] > IN_FRONT_DEPTH


@njit(cache=True, nogil=True)
def project_optical(points, intrinsics, dist):
    """Optical-frame points (n, 3), m -> distorted pixel coordinates (n, 2): the pinhole
    ``intrinsics`` (fx, fy, cx, cy) and the rational model's 8 ``dist`` coefficients (k1, k2,
    p1, p2, k3, k4, k5, k6; plumb-bob's with zeros), as OpenCV's projectPoints computes them
    (skew not used). Compiled (numba), for :func:`tt_perception.pipeline.ball_image`;
    :meth:`Camera.project` calls OpenCV itself."""
    k1, k2, p1, p2, k3, k4, k5, k6 = dist
    fx, fy, cx, cy = intrinsics
    uv = np.empty((points.shape[0], 2))
    for i in range(points.shape[0]):
        z = points[i, 2]
        w = 1.0 / z if z != 0.0 else 1.0
        x, y = points[i, 0] * w, points[i, 1] * w
        r2 = x * x + y * y
        radial = ((1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
                  / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        uv[i, 0] = fx * xd + cx
        uv[i, 1] = fy * yd + cy
    return uv


def file_error(what, path):
    """Why the file ``path`` given as ``what`` cannot be read, or ''."""
    if not os.path.exists(path):
        return f'{what} {path}: no such file'
    if not os.path.isfile(path):
        return f'{what} {path}: not a file'
    if not os.access(path, os.R_OK):
        return f'{what} {path}: cannot read: permission denied'
    return ''


def read_yaml(path, what):
    """The mapping at the top of the YAML file ``path``; raises CalibrationError naming it as
    ``what`` (no such file, a folder, not readable YAML, empty, not a mapping)."""
    error = file_error(what, path)
    if error:
        raise CalibrationError(error)
    try:
        with open(path, encoding='utf-8') as f:
            data = load_yaml(f)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise CalibrationError(
            f'{what} {path}: not readable YAML ({one_line_reason(exc)})') from None
    if data is None:
        raise CalibrationError(f'{what} {path}: empty')
    if not isinstance(data, dict):
        raise CalibrationError(f'{what} {path}: expected a mapping at the top level')
    return data


def _matrix(data, key, rows, cols, path):
    entry = data.get(key)
    values = entry.get('data') if isinstance(entry, dict) else entry
    if values is None:
        raise CalibrationError(f'camera_info {path}: {key} missing')
    try:
        array = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise CalibrationError(f'camera_info {path}: {key} is not a list of numbers') from None
    if array.size != rows * cols:
        raise CalibrationError(
            f'camera_info {path}: {key} needs {rows * cols} numbers, has {array.size}')
    if not np.all(np.isfinite(array)):
        raise CalibrationError(f'camera_info {path}: {key} has a non-finite number')
    return array.reshape(rows, cols)


def load_camera_info(path):
    """Read a ROS camera_info YAML -> dict(width, height, K (3,3), dist (5,), name).

    Raises :class:`CalibrationError` (one line) when the file is missing or inconsistent.
    """
    data = read_yaml(path, 'camera_info')
    try:
        size = data['image_width'], data['image_height']
        if any(isinstance(v, bool) or not float(v).is_integer() for v in size):
            raise ValueError        # 640.5 was cut to 640, true read as 1
        width, height = (int(v) for v in size)
    except (KeyError, TypeError, ValueError):
        raise CalibrationError(
            f'camera_info {path}: image_width/image_height missing or not integers') from None
    if width <= 0 or height <= 0:
        raise CalibrationError(f'camera_info {path}: image size {width}x{height} not positive')
    K = _matrix(data, 'camera_matrix', 3, 3, path)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[2, 2] != 1.0 or np.any(K[2, :2] != 0):
        raise CalibrationError(f'camera_info {path}: camera_matrix is not a pinhole matrix '
                               '(fx, fy > 0, last row 0 0 1)')
    if not (0.0 <= K[0, 2] <= width and 0.0 <= K[1, 2] <= height):
        raise CalibrationError(f'camera_info {path}: principal point ({K[0, 2]:g}, '
                               f'{K[1, 2]:g}) outside the {width}x{height} image')
    model = data.get('distortion_model', 'plumb_bob')
    if model not in ('plumb_bob', 'rational_polynomial'):
        raise CalibrationError(f'camera_info {path}: distortion_model {model!r} not supported '
                               '(plumb_bob or rational_polynomial)')
    if 'distortion_coefficients' not in data:
        # Read as none, a lens's distortion put the ball centimetres off without a word.
        raise CalibrationError(f'camera_info {path}: distortion_coefficients missing (a lens '
                               'without distortion: data: [0, 0, 0, 0, 0])')
    entry = data['distortion_coefficients']
    try:
        values = entry.get('data') if isinstance(entry, dict) else entry
        if isinstance(values, (str, bytes)) or any(isinstance(v, bool) for v in values):
            raise TypeError
        dist = np.asarray(values, dtype=float)
    except (TypeError, ValueError):     # 'k1', a ragged list, a string of numbers, None
        dist = np.empty(0)
    if dist.size not in DISTORTION_SIZES or not np.all(np.isfinite(dist)):
        raise CalibrationError(f'camera_info {path}: distortion_coefficients needs 4, 5 or 8 '
                               'numbers (plumb_bob: k1, k2, p1, p2[, k3]; rational_polynomial: '
                               'k1, k2, p1, p2, k3, k4, k5, k6)')
    return {'width': width, 'height': height, 'K': K, 'dist': dist,
            'name': str(data.get('camera_name', ''))}


def save_camera_info(path, name, width, height, K, dist):
    """Write a ROS camera_info YAML (the layout ``camera_calibration`` writes)."""
    K = np.asarray(K, dtype=float)
    P = np.hstack([K, np.zeros((3, 1))])
    data = {
        'image_width': int(width), 'image_height': int(height), 'camera_name': name,
        'camera_matrix': {'rows': 3, 'cols': 3, 'data': K.ravel().tolist()},
        'distortion_model': 'plumb_bob',
        'distortion_coefficients': {'rows': 1, 'cols': 5,
                                    'data': np.asarray(dist, dtype=float).ravel().tolist()},
        'rectification_matrix': {'rows': 3, 'cols': 3, 'data': np.eye(3).ravel().tolist()},
        'projection_matrix': {'rows': 3, 'cols': 4, 'data': P.ravel().tolist()},
    }
    with open(path, 'w', encoding='utf-8') as f:
        yaml.safe_dump(data, f, sort_keys=False)


MIN_BASELINE = 0.05
"""Least distance between two cameras' optical centres of a rig, m. Two cameras at one place
see the ball along one ray: no depth, a singular triangulation. 5 cm is far below any
baseline that measures depth at the table (at 3 m, half a pixel of noise over 5 cm is ~0.2 m
of depth; a table rig's cameras are a metre or more apart) and far above the rounding of a
pose written out by hand, so it refuses a copy-pasted or mis-entered pose and nothing else."""


def baseline_error(cameras, min_baseline=MIN_BASELINE):
    """Why ``cameras`` cannot triangulate, or '': the first two whose optical centres
    (C = -R^T t) are less than ``min_baseline`` (m) apart, with their distance."""
    for i, a in enumerate(cameras):
        for b in cameras[i + 1:]:
            gap = float(np.linalg.norm(a.centre - b.centre))
            if gap < min_baseline:
                return (f'cameras {a.name} and {b.name} are {gap:.3f} m apart: triangulation '
                        f'needs a baseline of at least {min_baseline:g} m')
    return ''


@dataclasses.dataclass
class Rig:
    """The cameras of a rig file, in file order (camera 0 is the time reference)."""

    cameras: list
    fps: float
    frame_id: str = 'table'
    path: str = ''


MAX_TIME_OFFSET_S = 1.0
"""Largest ``time_offset`` of a rig's camera, s: the span tt-perceive searches when it
estimates one (:mod:`tt_perception.sync`); 5 (ms meant) found no ball, without a word."""

RIG_KEYS = ('frame_id', 'fps', 'cameras')
CAMERA_KEYS = ('name', 'camera_info', 'source', 'rotation', 'translation', 'time_offset',
               'readout_time', 'white_bgr')
"""The keys of a rig file and of each of its cameras (DESIGN.md, "Data formats")."""


def _known_keys(mapping, known, where):
    """CalibrationError naming the first key of ``mapping`` not in ``known``: a misspelt
    optional key (``time_ofset``) would otherwise be ignored without a word."""
    unknown = [str(k) for k in mapping if k not in known]
    if unknown:
        raise CalibrationError(f"{where}: unknown key '{unknown[0]}' (known: "
                               f"{', '.join(known)})")


def _readout_time(value, fps, where):
    """A camera's ``readout_time`` (s) from its rig entry, checked: a number from 0 to the frame
    period (a rolling shutter reads its rows within one frame)."""
    try:
        if isinstance(value, bool):
            raise TypeError
        readout = float(value)
    except (TypeError, ValueError):
        raise CalibrationError(f'{where}: readout_time is not a number') from None
    if not 0.0 <= readout <= 1.0 / fps:     # nan too
        raise CalibrationError(f'{where}: readout_time {readout:g} s is not within [0, '
                               f'{1.0 / fps:.4g}] s, the frame period at {fps:g} fps '
                               '(seconds, not milliseconds)')
    return readout


def _white_bgr(value, where):
    """A camera's ``white_bgr`` from its rig entry, checked (three positive numbers, any
    scale: a pixel of a white surface) and scaled to its largest 1."""
    try:
        if isinstance(value, (str, bytes)) or any(isinstance(v, bool) for v in value):
            raise TypeError
        white = np.array(value, dtype=float)
    except (TypeError, ValueError):
        white = np.full(0, np.nan)
    if white.shape != (3,) or not np.all(np.isfinite(white)) or not np.all(white > 0.0):
        raise CalibrationError(f'{where}: white_bgr must be 3 positive numbers, the B, G, R of '
                               f'a white surface in its images (e.g. [150, 200, 240]), not '
                               f'{value!r}')
    return tuple(float(v) for v in white / white.max())


def load_rig(path, min_cameras=1, min_baseline=MIN_BASELINE, need_source=False):
    """Read and validate a rig file (DESIGN.md) and its camera_info files -> :class:`Rig`.

    Raises :class:`CalibrationError` with one line naming the file and the field at fault,
    when the rig has fewer than ``min_cameras`` cameras, or when two cameras' optical centres
    are less than ``min_baseline`` (m, :data:`MIN_BASELINE`; 0: not checked, for the pose
    command, which sets the poses of a rig whose cameras may all start at one place) apart,
    or, with ``need_source`` (perception_node, tt-perceive), when a camera has no source.
    """
    data = read_yaml(path, 'rig')
    base = os.path.dirname(os.path.abspath(path))
    _known_keys(data, RIG_KEYS, f'rig {path}')
    try:
        fps = data.get('fps', 0.0)
        if isinstance(fps, bool):
            raise TypeError         # YAML's true was read as 1 fps
        fps = float(fps)
    except (TypeError, ValueError):
        raise CalibrationError(f'rig {path}: fps is not a number') from None
    if not (math.isfinite(fps) and fps > 0.0):
        raise CalibrationError(f'rig {path}: fps must be a positive number')
    entries = data.get('cameras')
    if not isinstance(entries, list) or not entries:
        raise CalibrationError(f'rig {path}: cameras must be a non-empty list')
    cameras = []
    for i, entry in enumerate(entries):
        where = f'rig {path}: cameras[{i}]'
        if not isinstance(entry, dict):
            raise CalibrationError(f'{where} is not a mapping')
        name = str(entry.get('name', f'cam{i}'))
        _known_keys(entry, CAMERA_KEYS, f'{where} ({name})')
        if 'camera_info' not in entry:
            raise CalibrationError(f'{where} ({name}): camera_info missing')
        info = load_camera_info(os.path.join(base, str(entry['camera_info'])))
        for key in ('rotation', 'translation'):
            if key not in entry:
                raise CalibrationError(f'{where} ({name}): {key} missing (the pose takes table '
                                       'points into the camera frame: x_cam = R x_table + t)')
        try:
            R = np.asarray(entry.get('rotation'), dtype=float).reshape(3, 3)
            t = np.asarray(entry.get('translation'), dtype=float).reshape(3)
        except (TypeError, ValueError):
            raise CalibrationError(f'{where} ({name}): rotation needs 9 numbers and '
                                   'translation 3') from None
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise CalibrationError(f'{where} ({name}): pose has a non-finite number')
        if translation_error(t):
            raise CalibrationError(f'{where} ({name}): {translation_error(t)}')
        off, det = np.abs(R @ R.T - np.eye(3)).max(), np.linalg.det(R)
        if off > ROTATION_TOLERANCE or abs(det - 1.0) > ROTATION_TOLERANCE:
            hint = ("a reflection: one axis flipped (a left-handed frame, or the image's y "
                    'taken up instead of down)' if off <= ROTATION_TOLERANCE and det < 0 else
                    f'tolerance {ROTATION_TOLERANCE:g}; numbers rounded to 3 decimals are '
                    '1e-3 off: give at least 5')
            raise CalibrationError(
                f'{where} ({name}): rotation is not a rotation matrix (R R^T = I, det R = 1): '
                f'R R^T is up to {off:.1g} off I, det R = {det:.6g} ({hint})')
        offset = entry.get('time_offset')
        if offset is not None:
            try:
                if isinstance(offset, bool):    # YAML's true: 1 s
                    raise TypeError
                offset = float(offset)
            except (TypeError, ValueError):
                raise CalibrationError(f'{where} ({name}): time_offset is not a number') \
                    from None
            if not abs(offset) <= MAX_TIME_OFFSET_S:     # nan too
                raise CalibrationError(
                    f'{where} ({name}): time_offset {offset:g} s is not within '
                    f'+-{MAX_TIME_OFFSET_S:g} s (seconds, not milliseconds)')
        readout = _readout_time(entry.get('readout_time', 0.0), fps, f'{where} ({name})')
        white = _white_bgr(entry.get('white_bgr', (1.0, 1.0, 1.0)), f'{where} ({name})')
        source = entry.get('source')
        source = '' if source is None else str(source).strip()      # 0: /dev/video0
        if need_source and not source:
            # An empty source was the rig's own folder, read as a sequence of its images.
            raise CalibrationError(f'{where} ({name}): no source (a video file, a folder of '
                                   'images, a V4L2 device or an image topic)')
        cameras.append(Camera(name, info['width'], info['height'], info['K'], info['dist'],
                              R, t, source=source, time_offset=offset, readout_time=readout,
                              white_bgr=white,
                              info_file=str(entry['camera_info'])))
    if len(cameras) < min_cameras:
        raise CalibrationError(f'rig {path}: needs at least {min_cameras} cameras, has '
                               f'{len(cameras)}')
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise CalibrationError(f'rig {path}: camera names are not unique: {names}')
    error = baseline_error(cameras, min_baseline)
    if error:
        raise CalibrationError(f'rig {path}: {error}')
    frame_id = data.get('frame_id', 'table')
    if frame_id != 'table':         # states in it were dropped by prediction_node, each one
        raise CalibrationError(f"rig {path}: frame_id {frame_id!r}: the poses are in the "
                               "table frame (MODEL.md), frame_id 'table'")
    return Rig(cameras, fps, frame_id, os.path.abspath(path))


def set_camera_pose(path, index, R, t):
    """Write camera ``index``'s pose (R (3, 3), t (3,), table frame to camera) into the rig
    file ``path``, leaving the rest of the file as it is: its comments, key order and other
    cameras (ruamel.yaml's round trip). The file is replaced whole (a temporary file renamed
    over it), so an interrupted write leaves the old rig."""
    from ruamel.yaml import YAML
    from ruamel.yaml.comments import CommentedSeq

    yaml_rt = YAML()
    yaml_rt.preserve_quotes = True
    yaml_rt.width = 4096          # a pose on one line each (wrapped lines get trailing blanks)
    with open(path, encoding='utf-8') as f:
        data = yaml_rt.load(f)
    entry = data['cameras'][index]
    for key, values in (('rotation', np.asarray(R).ravel()), ('translation', t)):
        seq = CommentedSeq(float(v) for v in values)
        seq.fa.set_flow_style()
        entry[key] = seq
    text = io.StringIO()
    yaml_rt.dump(data, text)
    replace_file(path, text.getvalue())


def save_rig(path, rig):
    """Write a rig file (camera_info paths: each camera's ``info_file``, else NAME.yaml)."""
    entries = []
    for cam in rig.cameras:
        entry = {
            'name': cam.name,
            'camera_info': cam.info_file or f'{cam.name}.yaml',
            'source': cam.source,
            'rotation': [float(v) for v in cam.R.ravel()],
            'translation': [float(v) for v in cam.t],
        }
        if cam.time_offset is not None:
            entry['time_offset'] = float(cam.time_offset)
        if cam.readout_time:
            entry['readout_time'] = float(cam.readout_time)
        if min(cam.white_bgr) < 1.0:
            entry['white_bgr'] = [float(v) for v in cam.white_bgr]
        entries.append(entry)
    data = {'frame_id': rig.frame_id, 'fps': float(rig.fps), 'cameras': entries}
    with open(path, 'w', encoding='utf-8') as f:
        yaml.safe_dump(data, f, sort_keys=False, default_flow_style=None)


def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """Rotation R and translation t of a camera at ``eye`` looking at ``target`` (table frame).

    The optical z axis points at the target, x to the right of the view, y down.
    """
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    return R, -R @ eye
