"""Frame sources behind one interface: V4L2 devices, video files and image sequences, and
sensor_msgs/Image messages (from a topic or a bag).

A rig camera's ``source`` string is classified by :func:`source_kind`:

- ``/dev/videoN`` or a bare integer: a V4L2 device, opened through OpenCV's ``cv2.CAP_V4L2``
  backend with pixel format (FOURCC, e.g. MJPG), resolution, frame rate and exposure set;
- a path with a video or image extension, a printf pattern (``cam0/%06d.png``) or a folder
  of images (written with a final ``/``): a file source (relative to the rig file);
- anything else starting with ``/`` or a letter (``/cam0/image_raw``): an image topic.

:meth:`FrameSource.read` returns ``(t, frame)``: ``t`` the frame's time in s (V4L2: the
driver's buffer timestamp, CLOCK_MONOTONIC, moved to the wall clock; files: frame index over
the frame rate) and ``frame`` a BGR uint8 image, or ``None`` when no frame came. A device that
stops delivering is released and reopened every ``reopen_interval`` s; ``status`` says what
happened last, for the caller to report. A :class:`V4L2Source` also reads in two steps,
``grab()`` (reopen when away, take the frame and its time ``t`` or None) and ``retrieve()``
(decode it), for a reader that decodes only the frames it keeps.
"""

import os
import time

import cv2
import numpy as np

SOURCE_KINDS = ('v4l2', 'file', 'topic')
"""What :func:`source_kind` tells apart (docs/DEVELOPING.md: adding a camera source)."""

VIDEO_EXTENSIONS = ('.avi', '.mp4', '.mkv', '.mov', '.webm', '.png', '.jpg', '.jpeg', '.bmp')


def source_kind(source, base=''):
    """'v4l2', 'file' or 'topic' for a rig camera's ``source`` string; ``base``: the rig
    file's folder, which a relative folder of images is in (it was looked for in the
    current directory: the rig's 'cam0_frames' was taken for a topic from elsewhere)."""
    s = str(source).strip()
    if s.startswith('/dev/') or s.isdigit():
        return 'v4l2'
    if ('%' in s or s.endswith('/') or os.path.splitext(s)[1].lower() in VIDEO_EXTENSIONS
            or os.path.isdir(os.path.join(base, s))):
        return 'file'
    return 'topic'


def file_source_path(rig, cam):
    """The path of camera ``cam``'s video file or image sequence: its source, relative to
    the folder of the rig file ``rig``."""
    return os.path.join(os.path.dirname(rig.path), cam.source)


def file_source_error(rig, cam):
    """Why camera ``cam``'s video file cannot be used ('<path>: no such video file', frames
    not of its calibration's size, ...), or None; the file is opened and closed again."""
    try:
        source = VideoFileSource(file_source_path(rig, cam), rig.fps).open()
    except OSError as exc:
        return str(exc)
    try:
        error, _ = source.disagreement(cam, rig.fps)
    finally:
        source.close()
    return error or None


def camera_info_topic(image_topic):
    """The CameraInfo topic beside a camera's image topic, where perception_node subscribes
    it (``/cam0/image_raw`` -> ``/cam0/camera_info``; ``image_raw`` -> ``camera_info``)."""
    return (image_topic.rsplit('/', 1)[0] + '/camera_info' if '/' in image_topic
            else 'camera_info')


class FrameSource:
    """Common interface: ``open()``, ``read() -> (t, frame or None)``, ``close()``."""

    status = ''

    def open(self):
        raise NotImplementedError

    def read(self):
        raise NotImplementedError

    def close(self):
        pass


def _sequence_starts(pattern):
    """Whether the printf pattern of an image sequence (``cam0/%06d.png``) names a file at
    one of the indices 0 to 4, where FFmpeg's image2 reader looks for the first image; True
    for a pattern Python cannot expand (left to FFmpeg)."""
    try:
        return any(os.path.isfile(pattern % i) for i in range(5))
    except (TypeError, ValueError):
        return True


class VideoFileSource(FrameSource):
    """A video file or an image sequence (printf pattern or a directory of images)."""

    def __init__(self, path, fps):
        self.path = path
        self.fps = float(fps)
        self.capture = None
        self.index = 0
        self.declared = 0

    def open(self):
        path = self.path
        if os.path.isdir(path):
            names = sorted(n for n in os.listdir(path)
                           if os.path.splitext(n)[1].lower() in VIDEO_EXTENSIONS)
            if not names:
                raise OSError(f'{path}: no images in the directory')
            path = os.path.join(path, names[0])
            digits = ''.join(c for c in os.path.splitext(names[0])[0] if c.isdigit())
            if digits:
                stem = os.path.splitext(names[0])[0]
                path = os.path.join(self.path, stem[:-len(digits)] + f'%0{len(digits)}d'
                                    + os.path.splitext(names[0])[1])
        elif '%' not in path and not os.path.isfile(path):
            raise OSError(f'{path}: no such video file')
        elif '%' in path and not _sequence_starts(path):
            # Checked here: FFmpeg would log '[image2 @ 0x...] Could find no file ...' on
            # stderr before the one-line error below.
            raise OSError(f'{path}: no image matches the pattern (first index 0 to 4)')
        self.capture = cv2.VideoCapture(path)
        if not self.capture.isOpened():
            raise OSError(f'{path}: cannot be opened as a video or image sequence')
        self.index = 0
        self.declared = int(self.capture.get(cv2.CAP_PROP_FRAME_COUNT))
        return self

    def disagreement(self, cam, rig_fps):
        """``(error, warning)`` of the opened file against its camera ``cam`` (its
        calibration's image size) and the rig's ``rig_fps``, each '' when none: frames of
        another size than the calibration's would be measured with another camera's
        intrinsics (an error); a video file whose own rate differs by more than 1 % from the
        rig's is timed by the rig's (a warning). An image sequence has no rate of its own."""
        cap = self.capture
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        error = warning = ''
        if w > 0 and h > 0 and (w, h) != (cam.width, cam.height):
            error = (f'{self.path} is {w}x{h}, its calibration (camera_info) '
                     f'{cam.width}x{cam.height}')
        fps = cap.get(cv2.CAP_PROP_FPS)
        if (os.path.isfile(self.path) and fps > 0.0
                and abs(fps - rig_fps) > 0.01 * rig_fps):
            warning = (f"{self.path} is {fps:g} fps, the rig's fps {rig_fps:g}: its frames "
                       "are timed at the rig's")
        return error, warning

    def cut_short(self):
        """After the end: one line when fewer frames were read than the file's header
        declares (a cut or corrupt file), else ''. A frame of slack: some containers' counts
        are estimates."""
        if self.declared > 0 and self.index < self.declared - 1:
            return (f'{self.path}: video ended after {self.index} of the {self.declared} '
                    'frames its header declares (cut or corrupt?)')
        return ''

    def read(self):
        """Next frame ``(t, frame)``; ``(None, None)`` at the end of the file."""
        ok, frame = self.capture.read()
        if not ok:
            return None, None
        t = self.index / self.fps
        self.index += 1
        return t, frame

    def close(self):
        if self.capture is not None:
            self.capture.release()
            self.capture = None


class V4L2Source(FrameSource):
    """A V4L2 camera through OpenCV, reopened when it vanishes."""

    def __init__(self, device, width=640, height=480, fps=150.0, fourcc='MJPG',
                 exposure=None, reopen_interval=1.0, buffers=4):
        self.device = int(device) if str(device).isdigit() else str(device)
        self.width, self.height, self.fps = int(width), int(height), float(fps)
        self.fourcc = fourcc
        self.exposure = exposure
        self.reopen_interval = reopen_interval
        self.buffers = int(buffers)
        self.capture = None
        self.reopened = False
        self._next_try = 0.0
        self._delivered = False        # a frame came since the source was made
        # V4L2 buffer timestamps are CLOCK_MONOTONIC; this moves them to the wall clock.
        self._clock_offset = time.time() - time.monotonic()

    def open(self):
        path = f'/dev/video{self.device}' if isinstance(self.device, int) else self.device
        if not os.path.exists(path):
            # Checked first: OpenCV logs its own warning for an absent device at every try
            # (twice a second while the device is away).
            raise OSError(f'{self.device}: no such V4L2 device')
        cap = cv2.VideoCapture(self.device, cv2.CAP_V4L2)
        if not cap.isOpened():
            cap.release()
            raise OSError(f'{self.device}: V4L2 device cannot be opened')
        if self.fourcc:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*self.fourcc))
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        cap.set(cv2.CAP_PROP_FPS, self.fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, self.buffers)
        if self.exposure is not None:
            cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)            # V4L2 manual mode
            cap.set(cv2.CAP_PROP_EXPOSURE, float(self.exposure))
        self.capture = cap
        self.status = f'{self.device}: opened'
        return self

    def grab(self):
        """Take the next frame from the driver; its time ``t`` (s, wall clock: the driver's
        buffer timestamp), or None while the device is away. A device that is not open is
        (re)opened, at most every ``reopen_interval`` s; ``reopened`` says whether this grab
        brought back a device that had delivered frames before."""
        self.reopened = False
        if self.capture is None:
            now = time.monotonic()
            if now < self._next_try:
                return None
            self._next_try = now + self.reopen_interval
            try:
                self.open()
            except OSError as exc:
                self.status = str(exc)
                return None
            if self._delivered:
                self.status = f'{self.device}: reopened'
                self.reopened = True
        if not self.capture.grab():
            self._lost()
            return None
        self._delivered = True
        stamp_ms = self.capture.get(cv2.CAP_PROP_POS_MSEC)
        return stamp_ms * 1e-3 + self._clock_offset if stamp_ms > 0 else time.time()

    def retrieve(self):
        """The grabbed frame (BGR uint8), or None when it cannot be decoded."""
        if self.capture is None:
            return None
        ok, frame = self.capture.retrieve()
        return frame if ok else None

    def read(self):
        """Next frame ``(t, frame)``, or ``(None, None)`` while the device is away."""
        t = self.grab()
        if t is None:
            return None, None
        frame = self.retrieve()
        if frame is None:
            self._lost()
            return None, None
        return t, frame

    def _lost(self):
        """The device stopped delivering: released, reopened after ``reopen_interval`` s."""
        self.status = f'{self.device}: camera stopped delivering frames, reopening'
        self.close()
        self._next_try = time.monotonic() + self.reopen_interval

    def close(self):
        if self.capture is not None:
            self.capture.release()
            self.capture = None


def file_frames(rig, notes=None):
    """(t, camera_index, frame) of the rig's video files, one frame of each camera in turn at
    each frame index, ``t`` = index / fps on each camera's own clock. Raises OSError naming
    the camera when a source is not a file or cannot be read, or its frames are not of its
    calibration's size (:meth:`VideoFileSource.disagreement`). A video whose own rate is not
    the rig's, or that ends before its header's frame count, adds a line naming the camera to
    the list ``notes``.
    """
    base = os.path.dirname(rig.path)
    sources = {}
    try:
        for k, cam in enumerate(rig.cameras):
            if source_kind(cam.source, base) != 'file':
                raise OSError(f'camera {cam.name}: source {cam.source!r} is not a video file')
            try:
                sources[k] = VideoFileSource(file_source_path(rig, cam), rig.fps).open()
            except OSError as exc:
                raise OSError(f'camera {cam.name}: {exc}') from None
            error, warning = sources[k].disagreement(cam, rig.fps)
            if error:
                raise OSError(f'camera {cam.name}: {error}')
            if warning and notes is not None:
                notes.append(f'camera {cam.name}: {warning}')
        while sources:
            for k in sorted(sources):
                t, frame = sources[k].read()
                if frame is None:
                    ended = sources.pop(k)
                    ended.close()
                    short = ended.cut_short()
                    if notes is not None and short:
                        notes.append(f'camera {rig.cameras[k].name}: {short}')
                    continue
                yield t, k, frame
    finally:
        for src in sources.values():
            src.close()


def image_to_bgr(encoding, height, width, step, data):
    """A sensor_msgs/Image's pixels as a BGR uint8 array (H, W, 3).

    Supports bgr8, rgb8, bgra8, rgba8 and mono8; raises ValueError for other encodings or a
    buffer of the wrong size.
    """
    channels = {'bgr8': 3, 'rgb8': 3, 'bgra8': 4, 'rgba8': 4, 'mono8': 1}.get(encoding)
    if channels is None:
        raise ValueError(f'image encoding {encoding!r} not supported '
                         '(bgr8, rgb8, bgra8, rgba8, mono8)')
    buf = np.frombuffer(bytes(data) if not isinstance(data, np.ndarray) else data,
                        dtype=np.uint8)
    if height <= 0 or width <= 0 or step < width * channels or buf.size < height * step:
        raise ValueError(f'image buffer of {buf.size} bytes does not hold {width}x{height} '
                         f'{encoding} with step {step}')
    img = buf[:height * step].reshape(height, step)[:, :width * channels]
    img = img.reshape(height, width, channels) if channels > 1 else img.reshape(height, width)
    if encoding == 'rgb8':
        return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    if encoding == 'bgra8':
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    if encoding == 'rgba8':
        return cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    if encoding == 'mono8':
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(img)
