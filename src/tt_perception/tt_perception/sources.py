"""Frame sources behind one interface: V4L2 devices, video files and image sequences, and
sensor_msgs/Image messages (from a topic or a bag).

A rig camera's ``source`` string is classified by :func:`source_kind`:

- ``/dev/videoN`` or a bare integer: a V4L2 device, opened through OpenCV's ``cv2.CAP_V4L2``
  backend with pixel format (FOURCC, e.g. MJPG), resolution, frame rate and exposure set, and
  what the driver accepted read back (:class:`V4L2Source`); a path that exists but is no
  video device is refused (:func:`device_error`);
- a path with a video or image extension, a printf pattern (``cam0/%06d.png``), a folder
  of images (written with a final ``/``) or a file that exists: a file source (relative to
  the rig file);
- anything else starting with ``/`` or a letter (``/cam0/image_raw``): an image topic.

:meth:`FrameSource.read` returns ``(t, frame)``: ``t`` the frame's time in s (V4L2: the
driver's buffer timestamp, CLOCK_MONOTONIC, moved to the wall clock; files: frame index over
the frame rate) and ``frame`` a BGR uint8 image, or ``None`` when no frame came. A device that
stops delivering is released and reopened every ``reopen_interval`` s; ``status`` says what
happened last, for the caller to report. A :class:`V4L2Source` also reads in two steps,
``grab()`` (reopen when away, take the frame and its time ``t`` or None) and ``retrieve()``
(decode it), for a reader that decodes only the frames it keeps.
"""

import errno
import itertools
import math
import os
import re
import stat
import struct
import threading
import time

import cv2
import numpy as np

# FFmpeg's own log lines ('[mjpeg @ 0x...] overread 8', 32 of them around one damaged frame)
# on stderr, beside the one line that names the damage (VideoFileSource.damage): quiet
# unless the user set a level. OpenCV reads it when its FFmpeg backend first opens a file.
os.environ.setdefault('OPENCV_FFMPEG_LOGLEVEL', '-8')

SOURCE_KINDS = ('v4l2', 'file', 'topic')
"""What :func:`source_kind` tells apart (docs/DEVELOPING.md: adding a camera source)."""

VIDEO_EXTENSIONS = ('.avi', '.mp4', '.m4v', '.mkv', '.mov', '.webm', '.mpg', '.mpeg', '.ts',
                    '.mts', '.m2ts', '.wmv', '.flv', '.ogv', '.3gp',
                    '.png', '.jpg', '.jpeg', '.bmp')

AVI_BY_INDEX = 'fflags;+sortdts'
"""FFmpeg's option (in ``OPENCV_FFMPEG_CAPTURE_OPTIONS``) under which an AVI file is read
through its index (the demuxer's non-interleaved mode): each frame from the place, and with
the number (``CAP_PROP_PTS``), the index gives it, and a frame that cannot be decoded fails
one read, the next going on after it. Read in file order instead, FFmpeg resynchronises
silently past a damaged chunk, and the frames after it were numbered from the first one lost:
one MJPG frame overwritten in the middle of a file had the 47 after it each timed a frame
early (a track 7-10 mm off, exit 0 without a word). Only a file whose index is whole
(:func:`_avi_index_whole`) is: read through a damaged index, the frames it lost are skipped and
the rest numbered from the gap. Any other (cut before the index was written, an OpenDML file
over 1 GB) is read in file order."""
_CAPTURE_OPTIONS = threading.Lock()


def source_kind(source, base=''):
    """'v4l2', 'file' or 'topic' for a rig camera's ``source`` string; ``base``: the rig
    file's folder, which a relative folder of images is in (it was looked for in the
    current directory: the rig's 'cam0_frames' was taken for a topic from elsewhere)."""
    s = str(source).strip()
    if s.startswith('/dev/') or s.isdigit():
        return 'v4l2'
    if ('%' in s or s.endswith('/') or os.path.splitext(s)[1].lower() in VIDEO_EXTENSIONS
            or os.path.exists(os.path.join(base, s))):   # a folder, or a video of any name
        return 'file'
    return 'topic'


def file_source_path(rig, cam):
    """The path of camera ``cam``'s video file or image sequence: its source, relative to
    the folder of the rig file ``rig``."""
    return os.path.join(os.path.dirname(rig.path), cam.source)


def _avi_index_whole(path):
    """Whether the AVI file ``path`` ends in an index (idx1, the file's last chunk) of as
    many video frames as its main header declares, at increasing places: one that no
    overwrite has reached. Only the chunk headers and the index are read."""
    try:
        with open(path, 'rb') as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(52)
            if len(head) < 52 or head[:4] != b'RIFF' or head[8:12] != b'AVI ' \
                    or head[24:28] != b'avih':
                return False
            frames = struct.unpack_from('<I', head, 48)[0]
            pos = 12
            while pos + 8 <= size:
                f.seek(pos)
                tag, length = struct.unpack('<4sI', f.read(8))
                end = pos + 8 + length + (length & 1)
                if tag == b'idx1':
                    entries = np.frombuffer(f.read(length - length % 16), dtype=[
                        ('id', 'S4'), ('flags', '<u4'), ('offset', '<u4'), ('size', '<u4')])
                    video = entries[np.char.endswith(entries['id'], b'dc')
                                    | np.char.endswith(entries['id'], b'db')]['offset']
                    return (end >= size and 0 < frames == len(video)
                            and bool(np.all(np.diff(video.astype(np.int64)) > 0)))
                pos = end
    except (OSError, struct.error):
        pass
    return False


def _open_capture(path):
    """``(cv2.VideoCapture(path), by_index)``: an AVI file whose index is whole is read
    through it (``by_index`` True; :data:`AVI_BY_INDEX`, set for this open only, after any
    options the user has set)."""
    if not (path.lower().endswith('.avi') and os.path.isfile(path)
            and _avi_index_whole(path)):
        return cv2.VideoCapture(path), False
    key = 'OPENCV_FFMPEG_CAPTURE_OPTIONS'
    with _CAPTURE_OPTIONS:
        before = os.environ.get(key)
        os.environ[key] = f'{before}|{AVI_BY_INDEX}' if before else AVI_BY_INDEX
        try:
            return cv2.VideoCapture(path), True
        finally:
            if before is None:
                del os.environ[key]
            else:
                os.environ[key] = before


def camera_info_topic(image_topic):
    """The CameraInfo topic beside a camera's image topic, where perception_node subscribes
    it (``/cam0/image_raw`` -> ``/cam0/camera_info``; ``image_raw`` -> ``camera_info``; a
    compressed transport's ``/cam0/image_raw/compressed`` -> ``/cam0/camera_info``)."""
    if is_compressed_topic(image_topic):
        image_topic = image_topic.rstrip('/').rsplit('/', 1)[0]
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


IMAGE_EXTENSIONS = ('.png', '.jpg', '.jpeg', '.bmp', '.tif', '.tiff')
"""Files of a folder of images (:class:`ImageFolderCapture`)."""


class ImageFolderCapture:
    """A folder of numbered images behind the part of ``cv2.VideoCapture`` that
    :class:`VideoFileSource` and :class:`tt_perception.camstream.PacedVideoSource` use.

    Frame n is the image numbered first + n (the last digits of its name), so that a missing
    number is a lost frame and the images after it keep their times (FFmpeg's image2 reader
    stopped at the first gap and wanted the first number within 0-4). Where the numbers are
    no frame counts (a name without one, one number twice, more than half of them missing)
    the images are the frames in name order, digits compared as numbers (``by_name``). A
    missing or unreadable image fails its ``grab``/``read`` alone. Images are read with
    ``cv2.imread`` as 8-bit BGR. Written here: OpenCV reads a folder only as FFmpeg's printf
    pattern."""

    def __init__(self, folder, names):
        self.by_name = False
        self.first_number = None      # the number of frame 0 (None: read in name order)
        numbers = [_name_number(n) for n in names]
        if (None in numbers or len(set(numbers)) < len(numbers)
                or max(numbers) - min(numbers) + 1 > 2 * len(numbers)):
            # In name order: a name without a number, one number twice, or numbers that
            # are not frame counts (more than half of them missing: stamps in the names).
            files = [os.path.join(folder, n) for n in sorted(names, key=_natural)]
            self.by_name = True
        else:
            first = self.first_number = min(numbers)
            files = [None] * (max(numbers) - first + 1)
            for n, name in sorted(zip(numbers, names, strict=True)):
                files[n - first] = os.path.join(folder, name)
        self.files = files
        self.pos = -1
        self.size = (0, 0)
        for path in files:
            image = None if path is None else cv2.imread(path, cv2.IMREAD_COLOR)
            if image is not None:
                self.size = (image.shape[1], image.shape[0])
                break

    def isOpened(self):   # noqa: N802 (cv2.VideoCapture's name)
        return self.size != (0, 0)

    def grab(self):
        self.pos += 1
        return self.pos < len(self.files) and self.files[self.pos] is not None

    def retrieve(self):
        if not 0 <= self.pos < len(self.files) or self.files[self.pos] is None:
            return False, None
        image = cv2.imread(self.files[self.pos], cv2.IMREAD_COLOR)
        return image is not None, image

    def read(self):
        return self.retrieve() if self.grab() else (False, None)

    def get(self, prop):
        values = {cv2.CAP_PROP_FRAME_COUNT: len(self.files), cv2.CAP_PROP_PTS: self.pos,
                  cv2.CAP_PROP_FRAME_WIDTH: self.size[0],
                  cv2.CAP_PROP_FRAME_HEIGHT: self.size[1]}
        return float(values.get(prop, 0.0))

    def set(self, prop, value):
        return False

    def release(self):
        self.files = []
        self.size = (0, 0)


def _natural(name):
    """Sort key of a file name with its runs of digits compared as numbers (frame_2 before
    frame_10)."""
    return [(0, int(part), '') if part.isdigit() else (1, 0, part)
            for part in re.split(r'(\d+)', name) if part]


def _name_number(name):
    """The number in a file name's stem (its last run of digits), or None."""
    digits = re.findall(r'\d+', os.path.splitext(name)[0])
    return int(digits[-1]) if digits else None


class VideoFileSource(FrameSource):
    """A video file or an image sequence (printf pattern or a directory of images).

    An AVI file whose index is whole is read through it (``by_index``, :func:`_open_capture`):
    a frame that cannot be decoded is counted (``unreadable``) and the frames after it keep
    their numbers and times."""

    def __init__(self, path, fps):
        self.path = path
        self.fps = float(fps)
        self.capture = None
        self.by_index = False
        self.index = 0
        self.declared = 0
        self.unreadable = 0
        self.first_pts = None

    def open(self):
        path = self.path
        self.index = self.unreadable = 0
        self.first_pts = None
        if os.path.isdir(path):
            names = [n for n in os.listdir(path)
                     if os.path.splitext(n)[1].lower() in IMAGE_EXTENSIONS]
            if not names:
                raise OSError(f'{path}: no images in the directory')
            self.capture, self.by_index = ImageFolderCapture(path, names), True
            if not self.capture.isOpened():
                raise OSError(f'{path}: none of its images can be read')
            self.declared = len(self.capture.files)
            return self
        if '%' not in path and not os.path.isfile(path):
            raise OSError(f'{path}: no such video file')
        if '%' not in path and os.path.splitext(path)[1].lower() in IMAGE_EXTENSIONS:
            # FFmpeg reads one image as a video of one frame at 25 fps: a rate mismatch or
            # no track, not the mistake.
            raise OSError(f'{path}: a single image, not a video (give the folder of the '
                          "camera's images, or a printf pattern such as frame_%06d.jpg)")
        elif '%' in path and not _sequence_starts(path):
            # Checked here: FFmpeg would log '[image2 @ 0x...] Could find no file ...' on
            # stderr before the one-line error below.
            raise OSError(f'{path}: no image matches the pattern (first index 0 to 4)')
        self.capture, self.by_index = _open_capture(path)
        if not self.capture.isOpened():
            raise OSError(f'{path}: cannot be opened as a video or image sequence')
        self.declared = int(self.capture.get(cv2.CAP_PROP_FRAME_COUNT))
        return self

    def rate(self):
        """The video file's own frame rate (fps), or 0.0 when it has none (an image
        sequence) or does not say."""
        fps = self.capture.get(cv2.CAP_PROP_FPS)
        return float(fps) if os.path.isfile(self.path) and fps > 0.0 else 0.0

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
        fps = self.rate()
        if fps > 0.0 and abs(fps - rig_fps) > 0.01 * rig_fps:
            warning = (f"{self.path} is {fps:g} fps, the rig's fps {rig_fps:g}: its frames "
                       "are timed at the rig's")
        if getattr(cap, 'by_name', False):
            warning = (f'{self.path}: its images are read in name order, one frame each, '
                       'their numbers taken for no frame counts (a name without one, one '
                       'number twice, or more than half of them missing)')
        return error, warning

    def damage(self):
        """After the end: one line when fewer frames were read than the file's header
        declares (a cut or corrupt file; a frame of slack: some containers' counts are
        estimates) or some could not be decoded, else ''."""
        if self.declared > 0 and self.index < self.declared - 1:
            if '%' in self.path or os.path.isdir(self.path):       # no header: files
                text = (f'{self.path}: image sequence ended after {self.index} images, at '
                        'a gap in their numbers (the images after it are not read)')
            else:
                text = (f'{self.path}: video ended after {self.index} of the '
                        f'{self.declared} frames its header declares (cut or corrupt?)')
            return text + (f', {self.unreadable} of them unreadable' if self.unreadable
                           else '')
        if self.unreadable:
            what = ('missing or unreadable' if os.path.isdir(self.path)
                    else 'unreadable (corrupt?)')
            return (f'{self.path}: {self.unreadable} of its {self.index} frames {what}: '
                    'skipped, the others at their times')
        return ''

    def read(self):
        """Next frame ``(t, frame)``; ``(None, None)`` at the end of the file. Read through
        the index (``by_index``), a frame that cannot be decoded is ``(t, None)`` (counted in
        ``unreadable``) and the next read goes on after it."""
        ok, frame = self.capture.read()
        if not ok:
            if not (self.by_index and self.index < self.declared):
                return None, None
            frame = None
            self.unreadable += 1
        else:
            n = self.grabbed_number(self.index)
            if n > self.index:
                self.unreadable += n - self.index
                self.index = n
        t = self.index / self.fps
        self.index += 1
        return t, frame

    def grabbed_number(self, expected):
        """The number of the frame just read or grabbed, ``expected`` (the next in order) or
        later. Read through the index (``by_index``) it is the frame's own, from its PTS and
        the first frame's (MPEG-1 in AVI numbers from 1): a frame the decoder left out
        without failing the read (damaged, or an empty chunk, some recorders' dropped frame)
        does not give the next one its number and time."""
        if not self.by_index:
            return expected
        pts = int(self.capture.get(cv2.CAP_PROP_PTS))
        if self.first_pts is None:
            self.first_pts = pts - expected
        return max(expected, pts - self.first_pts)

    def close(self):
        if self.capture is not None:
            self.capture.release()
            self.capture = None


RATE_FRAMES = 20
"""Frame intervals of a camera whose median is compared with the rig's frame period
(:func:`rate_disagreement`): the tracker keeps a track's seeds and interpolates only within
a few periods of the rig's ``fps``, and a 30 fps camera in a rig of 150 gave no state and no
word."""
RATE_TOLERANCE = 0.2
"""Relative difference of the measured frame rate from the rig's ``fps`` that is named."""


def rate_disagreement(name, stamps, fps):
    """'' or one line naming camera ``name`` when the median interval of its frame
    ``stamps`` (s; the first RATE_FRAMES + 1 are enough) is not the period of the rig's
    ``fps`` within RATE_TOLERANCE."""
    intervals = np.diff(np.sort(np.asarray(stamps, dtype=float)))
    intervals = intervals[intervals > 0]
    if not intervals.size:
        return ''
    rate = 1.0 / float(np.median(intervals))
    if abs(rate - fps) <= RATE_TOLERANCE * fps:
        return ''
    return (f"camera {name}: its frames come at {rate:.3g} fps (their stamps), the rig's fps "
            f"is {fps:g}: set the rig's fps to the cameras' frame rate (tracking times the "
            'frames by it; no state may come otherwise)')


class FrameRateCheck:
    """Each camera's first RATE_FRAMES + 1 stamps, judged once against the rig's ``fps``
    (:func:`rate_disagreement`); ``names`` the cameras' names, ``cameras`` the indices
    judged."""

    def __init__(self, names, fps, cameras):
        self.names, self.fps = names, fps
        self.stamps = {k: [] for k in cameras}

    def add(self, k, stamp):
        """Camera ``k``'s frame stamped ``stamp`` (s): its one line once it has given
        RATE_FRAMES intervals at another rate, else ''."""
        if k not in self.stamps:
            return ''
        self.stamps[k].append(stamp)
        if len(self.stamps[k]) <= RATE_FRAMES:
            return ''
        return rate_disagreement(self.names[k], self.stamps.pop(k), self.fps)

    def drop(self, k):
        """Camera ``k`` no longer judged (its rate known otherwise)."""
        self.stamps.pop(k, None)

    def rest(self, least=6):
        """The lines of the cameras that gave fewer frames, judged from ``least`` on."""
        texts = [rate_disagreement(self.names[k], s, self.fps)
                 for k, s in self.stamps.items() if len(s) >= least]
        self.stamps = {}
        return [t for t in texts if t]


V4L2_MAJOR = 81
"""The device major number of Linux's video4linux devices (/dev/videoN)."""


def device_path(device):
    """The path of a rig camera's V4L2 ``source``: ``/dev/videoN`` for a bare integer N."""
    s = str(device).strip()
    return f'/dev/video{s}' if s.isdigit() else s


def device_error(device):
    """One line when the V4L2 ``device`` (path, or index N of /dev/videoN) exists but is no
    video device: not a character device (a regular file, a folder) or a character device of
    another driver than video4linux (/dev/null); else '' (a video device, or none there yet:
    a camera may be plugged in later). OpenCV tried such a path every second with its own
    warning."""
    path = device_path(device)
    try:
        st = os.stat(path)
    except OSError:
        return ''
    if not stat.S_ISCHR(st.st_mode):
        what = ('a folder' if stat.S_ISDIR(st.st_mode) else
                'a regular file' if stat.S_ISREG(st.st_mode) else 'not a character device')
        return (f'{path} is no V4L2 device ({what}; a camera is a character device, '
                '/dev/videoN: v4l2-ctl --list-devices lists them)')
    if os.major(st.st_rdev) != V4L2_MAJOR:
        return (f'{path} is no V4L2 device (a character device of major {os.major(st.st_rdev)}'
                f', video devices are {V4L2_MAJOR}: v4l2-ctl --list-devices lists them)')
    return ''


def fourcc_text(code):
    """A FOURCC read back from OpenCV (a float of 4 packed characters) as text, '' for 0."""
    code = int(code)
    text = code.to_bytes(4, 'little').decode('ascii', 'replace') if code > 0 else ''
    return text.rstrip('\x00 ')


class V4L2Source(FrameSource):
    """A V4L2 camera through OpenCV, reopened when it vanishes.

    After opening, what the driver accepted is read back (``driver_fps``, ``driver_size``,
    ``driver_fourcc``; 0 or '' where the driver does not say), and ``mismatch`` is one line
    when it differs from what was asked, else ''. ``width`` or ``height`` 0: the size is not
    asked, the driver's is kept."""

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
        self.driver_fps = 0.0
        self.driver_size = (0, 0)
        self.driver_fourcc = ''
        self.mismatch = ''
        self._next_try = 0.0
        self._delivered = False        # a frame came since the source was made
        # V4L2 buffer timestamps are CLOCK_MONOTONIC; this moves them to the wall clock.
        self._clock_offset = time.time() - time.monotonic()

    def open(self):
        path = device_path(self.device)
        if not os.path.exists(path):
            # Checked first: OpenCV logs its own warning for an absent device at every try
            # (twice a second while the device is away).
            raise OSError(f'{path}: no such V4L2 device')
        error = device_error(path)
        if error:                   # else OpenCV's own warning too, at every try
            raise OSError(error)
        if not os.access(path, os.R_OK | os.W_OK):
            raise OSError(f'{path}: permission denied (add the user to the group of the device,'
                          ' usually video, and log in again)')
        cap = cv2.VideoCapture(self.device, cv2.CAP_V4L2)
        if not cap.isOpened():
            cap.release()
            raise OSError(f'{path}: V4L2 device cannot be opened: {_open_failure(path)}')
        if self.fourcc:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*self.fourcc))
        if self.width > 0 and self.height > 0:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        cap.set(cv2.CAP_PROP_FPS, self.fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, self.buffers)
        if self.exposure is not None:
            cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)            # V4L2 manual mode
            cap.set(cv2.CAP_PROP_EXPOSURE, float(self.exposure))
        self.capture = cap
        self._read_back()
        self.status = f'{path}: opened'
        return self

    def _read_back(self):
        """What the driver accepted of the settings asked, and ``mismatch``."""
        cap = self.capture
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.driver_fps = fps if math.isfinite(fps) and fps > 0.0 else 0.0
        self.driver_size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH) or 0),
                            int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT) or 0))
        self.driver_fourcc = fourcc_text(cap.get(cv2.CAP_PROP_FOURCC) or 0)
        gives = []
        w, h = self.driver_size
        if self.width > 0 and self.height > 0 and w > 0 and h > 0 and (w, h) != (
                self.width, self.height):
            gives.append(f'{w}x{h} (asked {self.width}x{self.height})')
        if self.fourcc and self.driver_fourcc and self.driver_fourcc != self.fourcc:
            gives.append(f'{self.driver_fourcc} (asked {self.fourcc})')
        if self.driver_fps and abs(self.driver_fps - self.fps) > 0.01 * self.fps:
            gives.append(f"{self.driver_fps:g} fps (asked the rig's {self.fps:g}: set the "
                         "rig's fps to the cameras' rate)")
        self.mismatch = (f'{device_path(self.device)}: the driver gives ' + ', '.join(gives)
                         if gives else '')

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
                self.status = f'{device_path(self.device)}: reopened'
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
        self.status = (f'{device_path(self.device)}: camera stopped delivering frames, '
                       'reopening')
        self.close()
        self._next_try = time.monotonic() + self.reopen_interval

    def close(self):
        if self.capture is not None:
            self.capture.release()
            self.capture = None


def _open_failure(path):
    """Why the V4L2 device ``path``, which OpenCV could not open, cannot be: the error of
    opening it (errno), else the likely causes."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
    except OSError as exc:
        why = os.strerror(exc.errno) if exc.errno else str(exc)
        return why + (' (another program streams from it? fuser names it)'
                      if exc.errno == errno.EBUSY else '')
    os.close(fd)
    return (f'busy (another program streams from it? fuser {path} names it) or no capture '
            f'node (v4l2-ctl -d {path} --all says which)')


def rates_error(rig, sources):
    """One line when two of the opened video files ``sources`` ({camera index:
    :class:`VideoFileSource`}) run at rates more than 1 % apart, one of them the rig's
    ``fps``, else '': the frames are timed at the rig's fps, and the other camera's frames
    drift off (120 and 150 fps: a frame apart after four frames; no point triangulated, and
    the only word was a warning that blamed the poses). Files whose stated rates are neither
    the rig's (a phone's slow motion says 30 fps) are left to the warning of
    :meth:`VideoFileSource.disagreement`. Image sequences have no rate of their own."""
    rates = [(k, fps) for k, fps in ((k, src.rate()) for k, src in sorted(sources.items()))
             if fps > 0.0]

    def near(a, b):
        return abs(a - b) <= 0.01 * max(a, b)

    for (k0, fps0), (k, fps) in itertools.combinations(rates, 2):
        if not near(fps0, fps) and (near(fps0, rig.fps) or near(fps, rig.fps)):
            return (f'cameras {rig.cameras[k0].name} and {rig.cameras[k].name} run at '
                    f'different rates: {sources[k0].path} is {fps0:g} fps, '
                    f'{sources[k].path} {fps:g} fps (the rig has one fps for all its cameras: '
                    'record them at one rate)')
    return ''


def folder_starts_notes(rig, sources):
    """Lines for the list of notes when two of the opened sources ``sources`` ({camera
    index: :class:`VideoFileSource`}) are folders of numbered images whose numbers start
    apart: each folder's first image is its camera's frame 0, so a camera whose first images
    were lost is timed that many frames early (a camera 3 images short: a track 98 mm RMS
    off with time_offset 0, without a word; a new user's walk-through, 6 Dec 2026). Not
    said where the camera's ``time_offset`` already makes up for it."""
    starts = {k: src.capture.first_number for k, src in sorted(sources.items())
              if isinstance(src.capture, ImageFolderCapture)
              and src.capture.first_number is not None}
    if len(starts) < 2:
        return []
    ref = min(starts)
    notes = []
    for k, first in starts.items():
        offset = (starts[ref] - first) / rig.fps      # this camera's clock minus ref's
        given = rig.cameras[k].time_offset
        if k == ref or first == starts[ref] or (
                given is not None and abs(given - offset) < 0.5 / rig.fps):
            continue
        a, b = rig.cameras[ref].name, rig.cameras[k].name
        notes.append(f'cameras {a} and {b}: their folders of images start at numbers '
                     f"{starts[ref]} and {first}, and each folder's first image is its "
                     f"camera's frame 0: if the numbers count the same instants, {b} is "
                     f'timed {abs(first - starts[ref])} frame(s) off {a} (time_offset '
                     f'{offset:+.6g} s for {b} says so)')
    return notes


def lengths_notes(rig, sources):
    """Lines for the list of notes when one of the opened sources ``sources`` ({camera
    index: :class:`VideoFileSource`}) holds fewer frames than the longest (their headers'
    counts, image folders' numbers of images) by more than :data:`LENGTH_SLACK_FRAMES` and
    :data:`LENGTH_SLACK` of it: a camera stopped early, and past its end the ball has one
    camera fewer (with two, no 3-D state; 4 of 10 balls lost without a word before, a new
    user's walk-through, 6 Dec 2026)."""
    counts = {k: src.declared for k, src in sorted(sources.items()) if src.declared > 0}
    if len(counts) < 2:
        return []
    longest = max(counts, key=counts.get)
    most = counts[longest]
    return [f'camera {rig.cameras[k].name}: its {n} frames ({n / rig.fps:.2f} s) end before '
            f"camera {rig.cameras[longest].name}'s {most} ({most / rig.fps:.2f} s): after "
            f'{n / rig.fps:.2f} s the ball is seen by one camera fewer (with two cameras, no '
            f'3-D state; a camera stopped early?)'
            for k, n in counts.items()
            if most - n > max(LENGTH_SLACK_FRAMES, LENGTH_SLACK * most)]


LENGTH_SLACK_FRAMES = 3
"""Frames by which cameras' files may differ in length without a note (:func:`lengths_notes`):
cameras started and stopped by hand one after the other."""
LENGTH_SLACK = 0.02
"""The same as a fraction of the longest file's frames."""


def opened_notes(rig, sources):
    """The notes on the rig's opened file sources taken together (``sources``: {camera index:
    :class:`VideoFileSource`}): :func:`folder_starts_notes` and :func:`lengths_notes`, as
    both readers (:func:`file_sources_error`, :func:`file_frames`) give them."""
    return folder_starts_notes(rig, sources) + lengths_notes(rig, sources)


def file_sources_error(rig, notes=None):
    """Why the rig's video files cannot be used, in one line, or '': a camera's file missing,
    unreadable, without a frame or of another frame size than its calibration ('camera NAME:
    <path>: no such video file', :meth:`VideoFileSource.disagreement`), or two files at
    different rates (:func:`rates_error`). Each file is opened once and closed again.
    Folders of images numbered from different starts and files of different lengths add a
    line to the list ``notes`` (:func:`folder_starts_notes`, :func:`lengths_notes`)."""
    base = os.path.dirname(rig.path)
    sources = {}
    try:
        for k, cam in enumerate(rig.cameras):
            if source_kind(cam.source, base) != 'file':
                continue
            try:
                sources[k] = VideoFileSource(file_source_path(rig, cam), rig.fps).open()
            except OSError as exc:
                return f'camera {cam.name}: {exc}'
            error, _ = sources[k].disagreement(cam, rig.fps)
            if error:
                return f'camera {cam.name}: {error}'
            if not sources[k].capture.grab():       # a video of 0 frames ran without a word
                return f'camera {cam.name}: {sources[k].path}: {NO_FRAME}'
        if notes is not None:
            notes.extend(opened_notes(rig, sources))
        return rates_error(rig, sources)
    finally:
        for src in sources.values():
            src.close()


NO_FRAME = 'no frame can be read (an empty or broken video)'


def file_frames(rig, notes=None):
    """(t, camera_index, frame) of the rig's video files, one frame of each camera in turn at
    each frame index, ``t`` = index / fps on each camera's own clock; a frame that cannot be
    decoded is left out (the others keep their times). Raises OSError naming the camera when
    a source is not a file or cannot be read, or its frames are not of its calibration's size
    (:meth:`VideoFileSource.disagreement`), or naming two cameras whose files run at
    different rates (:func:`rates_error`), or when one gives no frame at all. A video whose
    own rate is not the rig's, that ends before its header's frame count or has frames that
    cannot be decoded, or that is shorter than another camera's (:func:`lengths_notes`) adds
    a line naming the camera to the list ``notes``.
    """
    base = os.path.dirname(rig.path)
    sources = {}
    try:
        for k, cam in enumerate(rig.cameras):
            kind = source_kind(cam.source, base)
            if kind != 'file':
                raise OSError(f'camera {cam.name}: source {cam.source!r} is not a video file'
                              + (' (an image topic: read from a bag, --bag)' if kind == 'topic'
                                 else ''))
            try:
                sources[k] = VideoFileSource(file_source_path(rig, cam), rig.fps).open()
            except OSError as exc:
                raise OSError(f'camera {cam.name}: {exc}') from None
            error, warning = sources[k].disagreement(cam, rig.fps)
            if error:
                raise OSError(f'camera {cam.name}: {error}')
            if warning and notes is not None:
                notes.append(f'camera {cam.name}: {warning}')
        error = rates_error(rig, sources)
        if error:
            raise OSError(error)
        if notes is not None:
            notes.extend(opened_notes(rig, sources))
        given = dict.fromkeys(sources, 0)
        while sources:
            for k in sorted(sources):
                t, frame = sources[k].read()
                if t is None:
                    ended = sources.pop(k)
                    ended.close()
                    if not given[k]:
                        raise OSError(f'camera {rig.cameras[k].name}: {ended.path}: {NO_FRAME}')
                    damage = ended.damage()
                    if notes is not None and damage:
                        notes.append(f'camera {rig.cameras[k].name}: {damage}')
                    continue
                if frame is not None:
                    given[k] += 1
                    yield t, k, frame
    finally:
        for src in sources.values():
            src.close()


_ENCODINGS = {
    # encoding: (bytes per pixel, conversion to BGR or None). The Bayer codes follow
    # OpenCV's naming, which reads the pattern one pixel in (cv_bridge's table):
    # bayer_rggb8 (red at the top left) is OpenCV's BayerBG. yuv422 is UYVY (ROS's name),
    # yuv422_yuy2 YUYV; both BT.601 limited range.
    'bgr8': (3, None), 'rgb8': (3, cv2.COLOR_RGB2BGR), 'bgra8': (4, cv2.COLOR_BGRA2BGR),
    'rgba8': (4, cv2.COLOR_RGBA2BGR), 'mono8': (1, cv2.COLOR_GRAY2BGR),
    'bayer_rggb8': (1, cv2.COLOR_BayerBG2BGR), 'bayer_bggr8': (1, cv2.COLOR_BayerRG2BGR),
    'bayer_gbrg8': (1, cv2.COLOR_BayerGR2BGR), 'bayer_grbg8': (1, cv2.COLOR_BayerGB2BGR),
    'yuv422': (2, cv2.COLOR_YUV2BGR_UYVY), 'yuv422_yuy2': (2, cv2.COLOR_YUV2BGR_YUY2),
}


def _uint8(data):
    """A message's ``data`` (bytes, a list of ints or a numpy array) as a uint8 array."""
    return np.frombuffer(data if isinstance(data, np.ndarray) else bytes(data), dtype=np.uint8)


def image_to_bgr(encoding, height, width, step, data):
    """A sensor_msgs/Image's pixels as a BGR uint8 array (H, W, 3).

    Supports the encodings of :data:`_ENCODINGS` (bgr8, rgb8, bgra8, rgba8, mono8, the four
    8-bit Bayer patterns, yuv422 and yuv422_yuy2); raises ValueError for other encodings or
    a buffer of the wrong size.
    """
    known = _ENCODINGS.get(encoding)
    if known is None:
        raise ValueError(f'image encoding {encoding!r} not supported '
                         f'({", ".join(_ENCODINGS)})')
    channels, conversion = known
    if channels == 2 and width % 2:
        raise ValueError(f'image encoding {encoding} needs an even width (two pixels share '
                         f'their colour), not {width}')
    buf = _uint8(data)
    if height <= 0 or width <= 0 or step < width * channels or buf.size < height * step:
        raise ValueError(f'image buffer of {buf.size} bytes does not hold {width}x{height} '
                         f'{encoding} with step {step}')
    img = buf[:height * step].reshape(height, step)[:, :width * channels]
    img = img.reshape(height, width, channels) if channels > 1 else img.reshape(height, width)
    if conversion is None:
        return np.ascontiguousarray(img)
    return cv2.cvtColor(np.ascontiguousarray(img), conversion)


def compressed_to_bgr(image_format, data):
    """A sensor_msgs/CompressedImage's pixels as a BGR uint8 array (H, W, 3): JPEG or PNG,
    colour or grey, as image_transport's compressed transport sends them (``format`` e.g.
    'bgr8; jpeg compressed bgr8', 'mono8; png compressed mono8', 'jpeg'). Raises ValueError
    for a depth image (compressedDepth) or data that does not decode."""
    if 'compresseddepth' in image_format.lower():
        raise ValueError(f'compressed image format {image_format!r} not supported (a depth '
                         'image; JPEG or PNG of a camera image)')
    buf = _uint8(data)
    image = cv2.imdecode(buf, cv2.IMREAD_COLOR) if buf.size else None
    if image is None:
        raise ValueError(f'compressed image ({len(buf)} bytes, format {image_format!r}) '
                         'does not decode as JPEG or PNG')
    return image


def is_compressed_topic(topic):
    """Whether the image topic ``topic`` carries sensor_msgs/CompressedImage: a name ending
    in ``/compressed`` (image_transport's compressed transport, ``/cam0/image_raw/compressed``)."""
    return topic.rstrip('/').endswith('/compressed')


def message_to_bgr(msg):
    """The BGR uint8 pixels of a sensor_msgs Image or CompressedImage message (rclpy's or
    rosbags'); ValueError naming what cannot be read."""
    if hasattr(msg, 'format'):
        return compressed_to_bgr(msg.format, msg.data)
    return image_to_bgr(msg.encoding, msg.height, msg.width, msg.step, msg.data)
