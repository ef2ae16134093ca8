"""tt-perceive: the perception pipeline offline, over the rig's video files or a bag.

    tt-perceive --rig RIG.yaml --out DIR [--bag BAG] [--colour white|orange|any] [--model FILE]
                [--out-bag BAG] [--response-gamma G] [--exposure S|auto]
                [--image-blur PX|auto] [--any-lighting] [--smooth]

Writes a trajectory folder (DESIGN.md): one CSV per track, ``track_NNN.csv`` with columns
``t,x,y,z,vx,vy,vz,wx,wy,wz`` (``t`` in s from the first frame of camera 0 for video files, the
image header stamps for a bag), and ``index.csv`` (``file,wx,wy,wz,label,source_id,spin_source``;
the spin columns are left empty and spin_source is ``estimated``: perception estimates spin,
it does not measure it, and tt-identify must not take it as measured); with
``--out-bag`` also a bag of tt_msgs/BallState on /ball/state. The states are the live node's
(each from the frames up to it); with ``--smooth`` each is given all of its track's frames,
the later ones too (:meth:`tt_perception.pipeline.Pipeline.smoothed`). The folder is written into a
temporary folder that then takes the place of DIR, so nothing of an earlier run stays; an
existing DIR must hold only such files (an earlier output), else it is refused. The bag is
written next to BAG and moved into place with the folder, so a failed run leaves neither.
Bad input: one line on stderr, exit status 2 for the rig, calibration, model, ``--out`` or
``--out-bag`` (which must be a new path that can be made, outside DIR), 1 for the data or a
failure to write; nothing is written then.

Video files have no common clock: a camera (other than camera 0) whose ``time_offset`` the
rig leaves out gets it estimated from the ball first (:mod:`tt_perception.sync`, one extra
pass of detection over the files), then refined from the centres fitted to the ball's
outline in the pass that estimates the cameras' blur (:func:`refine_offsets`), reported on
stderr.
"""

import argparse
import collections
from concurrent.futures import ThreadPoolExecutor
import contextlib
import csv
import dataclasses
import os
import pathlib
import re
import shutil
import sys
import tempfile

import numpy as np
from tt_prediction.ball import load_model
from tt_prediction.cli import add_version
from tt_prediction.staged import (
    creatable_error,
    interruptible,
    output_folder_error,
    staged_folder,
)
from tt_ros.errors import one_line_reason

from .camera import CalibrationError, load_rig
from .detect import (
    EXPOSURE_RANGE,
    IMAGE_BLUR_RANGE,
    RESPONSE_GAMMA_RANGE,
    BallDetector,
    DetectorConfig,
    estimate_exposure,
    estimate_exposure_and_blur,
    estimate_image_blur,
)
from .pipeline import Pipeline, TrackerConfig
from .sources import FrameRateCheck, file_frames, message_to_bgr
from .sync import estimate_offset, estimate_offset_tracks, image_tracks

IMAGE_TYPES = ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage')
"""Message types of a camera's images in a bag."""


class InputError(Exception):
    """Video files or bag that cannot be read."""


class OutputError(Exception):
    """An output that cannot be written (one line naming the option and the path)."""


def bag_frames(rig, bag, notes=None):
    """(t, camera_index, frame) of the sensor_msgs/Image (or CompressedImage) messages on the
    rig's image topics, in the bag's order, ``t`` the header stamp (s; the bag's record time
    for an image without one, with a line in ``notes``); a frame that cannot be
    read (an encoding not supported, data that does not decode) is None, for the pipeline to
    report. InputError when fewer than two of the
    rig's cameras have images in the bag (a topic declared without a message has none), or
    when a camera's first image is not of its calibration's size (as a video file's is
    refused); a camera without any adds a line to ``notes``."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    from tt_ros.bagfile import bag_problem
    topics = {cam.source: k for k, cam in enumerate(rig.cameras)}
    problem = bag_problem(bag)
    if problem:
        raise InputError(f'{bag}: not a readable rosbag2 bag: {problem}')
    try:
        reader = AnyReader([pathlib.Path(bag)],
                           default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except Exception as exc:     # rosbags raises several unrelated types for a bad bag
        raise InputError(f'{bag}: not a readable rosbag2 bag: {one_line_reason(exc)}') from None
    try:
        conns = [c for c in reader.connections
                 if c.topic in topics and c.msgtype in IMAGE_TYPES and c.msgcount]
        lacking = sorted(set(topics) - {c.topic for c in conns})
        if lacking:
            present = ', '.join(sorted(c.topic for c in reader.connections)) or 'none'
            names = ', '.join(f'{rig.cameras[topics[t]].name} ({t})' for t in lacking)
            if len(topics) - len(lacking) < 2:     # a point needs two cameras
                raise InputError(f'{bag}: no sensor_msgs/Image or CompressedImage for '
                                 f'camera(s) {names} (topics: {present})')
            if notes is not None:
                notes.append(f'{bag}: no sensor_msgs/Image or CompressedImage for camera(s) '
                             f'{names}: the others triangulate alone')
        sized = set()               # cameras whose first image had its calibration's size
        unstamped = set()           # cameras whose images have no header stamp
        rates = FrameRateCheck([c.name for c in rig.cameras], rig.fps, topics.values())
        for conn, recorded, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            k = topics[conn.topic]
            try:
                frame = message_to_bgr(msg)
            except ValueError:
                frame = None          # the pipeline reports the camera's missing frame
            if k not in sized:
                cam = rig.cameras[k]
                size = ((msg.width, msg.height) if hasattr(msg, 'width') else
                        None if frame is None else (frame.shape[1], frame.shape[0]))
                if size is not None and size != (cam.width, cam.height):
                    raise InputError(f'{bag}: camera {cam.name} ({conn.topic}): images '
                                     f'{size[0]}x{size[1]}, its calibration '
                                     f'{cam.width}x{cam.height}')
                if size is not None:
                    sized.add(k)
            t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            if t <= 0.0:            # a driver that leaves it unset: when the bag recorded it
                t = recorded * 1e-9
                if k not in unstamped and notes is not None:
                    notes.append(f'{bag}: camera {rig.cameras[k].name} ({conn.topic}): images '
                                 'without a header stamp, timed by when the bag recorded them '
                                 "(later than the exposure by the transport's delay, which "
                                 'varies: stamp the images at exposure)')
                unstamped.add(k)
            text = rates.add(k, t)
            if text and notes is not None:
                notes.append(f'{bag}: {text}')
            yield t, k, frame
        if notes is not None:                   # a bag shorter than RATE_FRAMES frames
            notes.extend(f'{bag}: {text}' for text in rates.rest())
    finally:
        reader.close()


def alone_in_frame(t):
    """Mask of the entries of ``t`` (frame times) that no other entry shares: the frames
    with a single detection, whose centre is not confused with another's."""
    times, counts = np.unique(t, return_counts=True)
    return np.isin(t, times[counts == 1])


def detections_per_camera(rig, frames, colours, detector_config=None):
    """Detections sure of their colour per camera over all frames, for each ball colour of
    ``colours`` (each frame decoded once, looked at by one detector per colour; the other
    settings from ``detector_config``): {colour: [(single, tracks) per camera]}, ``single``
    the frames with one detection, (times, normalised (n, 2)), and ``tracks`` every
    detection linked into image tracks (:func:`tt_perception.sync.image_tracks`)."""
    base = detector_config or DetectorConfig()
    detectors = {c: [BallDetector(dataclasses.replace(base, colour=c, white_bgr=cam.white_bgr),
                                  cam.focal)
                     for cam in rig.cameras]
                 for c in colours}
    found = {c: [([], []) for _ in rig.cameras] for c in colours}
    for t, k, frame in frames:
        for c in colours:
            dets = detectors[c][k].detect(frame) if frame is not None else []
            for d in dets:
                if d.colour_sure:
                    found[c][k][0].append(t)
                    found[c][k][1].append(rig.cameras[k].normalise([[d.u, d.v]])[0])
    out = {c: [] for c in colours}
    for c in colours:
        for t, x in found[c]:
            t, x = np.array(t), np.array(x).reshape(-1, 2)
            single = alone_in_frame(t)
            out[c].append(((t[single], x[single]), image_tracks(t, x, 1.0 / rig.fps)))
    return out


def _offset(cam0, camk, found0, foundk, fps):
    """(offset, cost) of camera k from the frames where each camera has a single detection;
    where they give none or an unreliable one (another moving thing in view beside the ball
    leaves too few such frames: a swinging disc put a 5 ms offset at -27 ms, a new user's
    walk-through, 29 Nov 2026), from image tracks (:func:`sync.estimate_offset_tracks`)."""
    offset, cost = estimate_offset(cam0, camk, *found0[0], *foundk[0], fps)
    if offset is not None and cost * camk.focal <= UNRELIABLE_OFFSET_PX:
        return offset, cost
    tracked = estimate_offset_tracks(cam0, camk, found0[1], foundk[1], fps)
    return tracked if tracked[1] < cost else (offset, cost)


UNRELIABLE_OFFSET_PX = 3.0
"""Median epipolar distance (pixels) above which an estimated time offset is reported as
unreliable (a right offset on a detected ball gives under a pixel)."""


def estimate_offsets(rig, colour, detector_config=None):
    """Fill in the missing ``time_offset`` of the rig's cameras from the ball's detections
    (:mod:`tt_perception.sync`; the detector's settings but its colour from
    ``detector_config``); returns one line per camera estimated. With ``colour``
    'any', the detections of a white and of an orange ball are both tried and the offset
    that puts its pairs nearer the epipolar lines kept: without a colour, the frames with
    the ball also have other moving things (a racket, an arm, shadows), and those with a
    single detection are mostly not the ball."""
    missing = [k for k, cam in enumerate(rig.cameras) if k > 0 and cam.time_offset is None]
    if not missing:
        return []
    # The files' clocks are compared; camera 0's own time_offset (a delay of its stamps, as
    # a V4L2 driver's readout) is taken off its frames, so the others' includes it.
    base = rig.cameras[0].time_offset or 0.0
    included = f" (camera 0's {base * 1e3:+.3f} ms included)" if base else ''
    as_camera_0 = "taken as camera 0's" if base else 'taken as 0'
    colours = ('white', 'orange') if colour == 'any' else (colour,)
    found = detections_per_camera(rig, file_frames(rig), colours,   # OSError: bad input
                                  detector_config)
    notes = []
    for k in missing:
        cam = rig.cameras[k]
        tried = [(*_offset(rig.cameras[0], cam, found[c][0], found[c][k], rig.fps), c)
                 for c in colours]
        tried = [t for t in tried if t[0] is not None]
        if not tried:
            cam.time_offset = base
            notes.append(f'warning: {cam.name}: too few ball detections to estimate its time '
                         f'offset, {as_camera_0} (set time_offset in the rig file)')
            continue
        offset, cost, used = min(tried, key=lambda t: t[1])
        cam.time_offset = float(offset) + base
        px = cost * cam.focal
        # With --colour any: the detector whose detections agree best (a white ball was
        # named 'the orange ball' when the orange test's did; a walk-through, 6 Dec 2026).
        which = f' (as the {used} detector finds it)' if len(colours) > 1 else ''
        notes.append(f'{cam.name}: time_offset {cam.time_offset * 1e3:+.3f} ms estimated from '
                     f'the ball{which}{included} (median epipolar distance {px:.2f} px)')
        if px > UNRELIABLE_OFFSET_PX:
            # With a colour given, the detections are the ball's: the rays do not meet. Not
            # used: a wrong offset matched a few frames by chance into a short false track,
            # and the poses' warning below was not given.
            cam.time_offset = base
            notes.append(f'warning: {cam.name}: that time offset is unreliable (above '
                         f'{UNRELIABLE_OFFSET_PX:g} px) and not used ({as_camera_0}): set '
                         'time_offset in the rig file'
                         + (' or give --colour' if colour == 'any' else '')
                         + " (or the rig's poses are off: a transposed rotation, a pose "
                         'in the other convention)')
    return notes


def record_fitted(pipeline, fitted):
    """From now on, append to ``fitted[k]`` the (time, u, v) of each centre that
    ``pipeline`` fits to the ball's outline in camera k's frames (the time the frame was
    given with, on its camera's clock; pixels)."""
    frame_time = [None]
    pipeline_detect = pipeline.detect

    def timed(t, k, frame, *args, **kwargs):
        frame_time[0] = t
        return pipeline_detect(t, k, frame, *args, **kwargs)

    def recording(k, detect):
        def detect_and_record(*args, **kwargs):
            found = detect(*args, **kwargs)
            fitted[k].extend((frame_time[0], d.u, d.v) for d in found if d.fitted)
            return found
        return detect_and_record

    pipeline.detect = timed
    for k, detector in enumerate(pipeline.detectors):
        detector.detect = recording(k, detector.detect)


REFINE_FITS_MIN = 20
"""Outline fits each camera needs before its time offset is refined from them."""


def refine_offsets(rig, fitted, cameras):
    """Refine the estimated ``time_offset`` of ``cameras`` (indices above 0) from the centres
    fitted to the ball's outline, ``fitted`` ([(t, u, v)] per camera, :func:`record_fitted`),
    within half a frame of the estimate: the blobs' centres it rests on lean toward the lit
    side, each camera's its own way, and took synth's hall orange ball (synchronised
    cameras) to -1.0 ms, 5.7 mm RMS off (a new user's walk-through, 5 Dec 2026). Kept where
    the fitted centres lie nearer their epipolar lines than :data:`UNRELIABLE_OFFSET_PX`;
    returns one line per camera refined. Only the frames with one fitted centre count (a
    ball's shadow or a highlight beside it can be fitted to its outline too)."""
    def points(k):
        t, u, v = np.array(fitted[k] or np.zeros((0, 3))).reshape(-1, 3).T
        one = alone_in_frame(t)
        if one.sum() < REFINE_FITS_MIN:
            return None
        return t[one], rig.cameras[k].normalise(np.column_stack([u[one], v[one]]))

    notes = []
    base = rig.cameras[0].time_offset or 0.0
    first = points(0)
    for k in cameras:
        cam, found = rig.cameras[k], points(k)
        if first is None or found is None:
            continue
        estimate = cam.time_offset - base
        offset, cost = estimate_offset(rig.cameras[0], cam, *first, *found, rig.fps,
                                       max_offset=0.5 / rig.fps, centre=estimate)
        if offset is None or cost * cam.focal > UNRELIABLE_OFFSET_PX:
            continue
        cam.time_offset = float(offset) + base
        notes.append(f'{cam.name}: its time offset refined to {cam.time_offset * 1e3:+.3f} ms '
                     f"from {len(found[0])} centres fitted to the ball's outline (median "
                     f'epipolar distance {cost * cam.focal:.2f} px)')
    return notes


BLUR_FITS = 400
"""Outline fits per camera that :func:`estimate_blurs` reads at most (the latest ones: a
camera that sees the ball less makes the pass longer, not the other's list)."""
BLUR_FITS_MIN = 30
"""Fewest outline fits a camera's blur is estimated from."""


def estimate_blurs(rig, frames, params=None, detector_config=None, exposure=False,
                   image_blur=True, fitted=None):
    """Each camera's exposure (s, with ``exposure``) and ``image_blur`` (px, with
    ``image_blur``) estimated from the outline fits of the ball in ``frames`` (both:
    :func:`tt_perception.detect.estimate_exposure_and_blur`; one: :func:`tt_perception.
    detect.estimate_exposure` or :func:`tt_perception.detect.estimate_image_blur`), tracked
    by a pipeline with ``detector_config``'s until every camera has :data:`BLUR_FITS` fits;
    returns (one (exposure, image_blur) pair per camera, one line per estimate). What is not
    estimated, or where a camera has fewer than :data:`BLUR_FITS_MIN` fits (with a warning),
    is ``detector_config``'s. ``fitted``: a list per camera, filled with the (time, u, v)
    of every centre fitted to the ball's outline in this pass (:func:`record_fitted`)."""
    pipeline = Pipeline(rig, params=params, detector_config=detector_config)
    for detector in pipeline.detectors:
        detector.fits = collections.deque(maxlen=BLUR_FITS)
    if fitted is not None:
        record_fitted(pipeline, fitted)
    run(frames, pipeline,
        until=lambda: all(len(d.fits) == BLUR_FITS for d in pipeline.detectors))

    def estimate(detector):
        """(exposure, blur, fits they rest on) of one camera's detector, as asked."""
        seconds, blur = detector.config.exposure, detector.config.image_blur
        fits = detector.fits if len(detector.fits) >= BLUR_FITS_MIN else []
        period = 1.0 / rig.fps
        if exposure and image_blur:
            return estimate_exposure_and_blur(fits, seconds, period)
        if exposure:
            found, n = estimate_exposure(fits, seconds, period)
            return found, blur, n
        found, n = estimate_image_blur(fits)
        return seconds, found, n

    # The refits run in numba without the GIL: one thread a camera.
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        found = list(pool.map(estimate, pipeline.detectors))
    settings, notes = [], []
    for cam, detector, (found_seconds, found_blur, n) in zip(rig.cameras, pipeline.detectors,
                                                              found, strict=True):
        seconds, blur = told = (detector.config.exposure, detector.config.image_blur)
        estimated = n >= BLUR_FITS_MIN
        if estimated:
            seconds, blur = max(found_seconds, EXPOSURE_RANGE[0]), found_blur
        lines = []
        if exposure:
            lines.append(('exposure', f'{seconds * 1e3:.2f} ms', f'{told[0]:g} s', '--exposure'))
        if image_blur:
            lines.append(('image_blur', f'{blur:.2f} px', f'{told[1]:g} px', '--image-blur'))
        for what, value, told_value, option in lines:
            notes.append(f'{cam.name}: {what} {value} estimated from {n} outline fits of the '
                         'ball' if estimated else
                         f'warning: {cam.name}: {len(detector.fits)} outline fit(s) of the ball, '
                         f'too few to estimate its {what}, {told_value} taken (set {option})')
        settings.append((seconds, blur))
    return settings, notes


def pipeline_with_estimated_blurs(rig, frames, params=None, detector_config=None,
                                  tracker_config=None, exposure=False, image_blur=True,
                                  refine=()):
    """A new :class:`Pipeline` whose detectors each have their camera's exposure (with
    ``exposure``) and ``image_blur`` (with ``image_blur``) estimated from ``frames``
    (:func:`estimate_blurs`, tracking with ``detector_config``'s), and the estimate's
    lines. The time offsets of the cameras ``refine`` (indices; estimated from the blobs by
    :func:`estimate_offsets`) are refined first from the same pass's centres fitted to the
    outline (:func:`refine_offsets`)."""
    fitted = [[] for _ in rig.cameras] if refine else None
    settings, notes = estimate_blurs(rig, frames, params, detector_config, exposure,
                                     image_blur, fitted)
    if refine:
        notes = refine_offsets(rig, fitted, refine) + notes
    pipeline = Pipeline(rig, params=params, detector_config=detector_config,
                        tracker_config=tracker_config)
    for detector, (seconds, blur) in zip(pipeline.detectors, settings, strict=True):
        detector.config.exposure = seconds
        detector.config.image_blur = blur
    return pipeline, notes


def run(frames, pipeline, until=None):
    """All estimates of the pipeline over ``frames``, and the first error met per camera;
    stopped early when ``until()`` is true after a frame."""
    estimates, errors = [], {}
    t_ref = None
    for t, k, frame in frames:
        if t_ref is None:
            t_ref = float(np.floor(t))     # keep sub-microsecond resolution on epoch stamps
        estimates += [(t_ref, e) for e in pipeline.process(t - t_ref, k, frame)]
        if pipeline.last_error and k not in errors:
            errors[k] = pipeline.last_error
        if until is not None and until():
            break
    if t_ref is not None:      # the states of a track the last frames confirmed
        estimates += [(t_ref, e) for e in pipeline.finish()]
    return estimates, errors


def write_tracks(out, estimates, label, out_bag=None, frame_id='table'):
    """Write one CSV per track and index.csv into a temporary folder, then put it in the place
    of ``out`` (staged_folder: an earlier run's files do not stay, an error leaves ``out`` as
    it was); with ``out_bag`` also the bag (:func:`write_bag`, staged next to it and moved in
    just before the folder, removed again if the folder's move fails). Returns the file
    names; raises :class:`OutputError` (nothing written)."""
    bag_placed = False
    try:
        with staged_folder(out, 'tt-perceive') as tmp:
            names = _write_track_files(tmp, estimates, label)
            if out_bag:
                from rosbags.rosbag2 import WriterError
                from tt_ros.bagfile import BagError
                with _staged_bag(out_bag) as bag_tmp:
                    try:
                        write_bag(bag_tmp, estimates, frame_id)
                    except (OSError, BagError, WriterError) as exc:
                        raise OutputError(f'--out-bag {out_bag}: cannot write: '
                                          f'{one_line_reason(exc)}') from None
                bag_placed = True
    except BaseException as exc:    # the folder not moved in (Ctrl-C too): nor is the bag
        if bag_placed:
            shutil.rmtree(out_bag, ignore_errors=True)
        if isinstance(exc, OSError):
            raise OutputError(f'--out {out}: cannot write: {one_line_reason(exc)}') from None
        raise
    return names


@contextlib.contextmanager
def _staged_bag(path):
    """Yield a path next to ``path`` (same folder, so same disk) to write a new bag into; it
    is moved to ``path`` when the block ends without an exception, else removed (as
    :func:`tt_prediction.staged.staged_folder` does for a folder)."""
    target = os.path.abspath(path)
    parent = os.path.dirname(target)
    try:
        os.makedirs(parent, exist_ok=True)
        holder = tempfile.mkdtemp(prefix='.tt-perceive-bag-', dir=parent)
    except OSError as exc:
        raise OutputError(f'--out-bag {path}: cannot write: {one_line_reason(exc)}') from None
    try:
        tmp = os.path.join(holder, os.path.basename(target))   # the bag's files take its name
        yield tmp
        if os.path.lexists(target):          # made by someone else during the run
            raise OutputError(f'--out-bag {path}: already exists (give a new bag)')
        try:
            os.rename(tmp, target)
        except OSError as exc:
            raise OutputError(f'--out-bag {path}: cannot write: {one_line_reason(exc)}') from None
    finally:
        shutil.rmtree(holder, ignore_errors=True)


def out_bag_error(out_bag, out):
    """Why a new bag cannot be written at ``out_bag``, or '' (checked before any work, as
    :func:`tt_prediction.staged.output_folder_error` checks ``--out``): it must not exist (not
    even as a dangling link), must be outside the output folder ``out`` (which is replaced
    whole) and not hold it, and a folder must be makeable in its nearest existing
    ancestor."""
    if not out_bag:
        return '--out-bag: an empty path (give a new bag)'
    if os.path.lexists(out_bag):
        return f'--out-bag {out_bag}: already exists (give a new bag)'
    bag, folder = os.path.realpath(out_bag), os.path.realpath(out)
    if bag == folder or os.path.commonpath([bag, folder]) in (bag, folder):
        return f'--out-bag {out_bag}: inside --out {out} or holding it (give another path)'
    return creatable_error(out_bag, '--out-bag')


def _write_track_files(tmp, estimates, label):
    """Write the track CSVs and index.csv into the folder ``tmp``; returns the file names."""
    tracks = {}
    for t_ref, e in estimates:
        tracks.setdefault(e.track_id, []).append((t_ref + e.t, e.state))
    names = [f'track_{n:03d}.csv' for n in range(1, len(tracks) + 1)]
    for name, track_id in zip(names, sorted(tracks), strict=True):
        with open(os.path.join(tmp, name), 'w', newline='', encoding='utf-8') as f:
            w = csv.writer(f)
            w.writerow(['t', 'x', 'y', 'z', 'vx', 'vy', 'vz', 'wx', 'wy', 'wz'])
            for t, s in tracks[track_id]:
                w.writerow([f'{t:.6f}'] + [f'{v:.6f}' for v in s])
    with open(os.path.join(tmp, 'index.csv'), 'w', newline='', encoding='utf-8') as f:
        w = csv.writer(f)
        w.writerow(['file', 'wx', 'wy', 'wz', 'label', 'source_id', 'spin_source'])
        for name, track_id in zip(names, sorted(tracks), strict=True):
            w.writerow([name, '', '', '', label, track_id, 'estimated'])
    return names


OUTPUT_FILE = re.compile(r'track_\d{3,}\.csv|index\.csv')
"""The files tt-perceive writes into its output folder."""


def write_bag(path, estimates, frame_id):
    """Write the estimates as tt_msgs/BallState on /ball/state into a new MCAP bag."""
    from rclpy.serialization import serialize_message
    from tt_ros.bagfile import BagWriter

    from .node import STATE_TOPIC, ball_state_message
    writer = BagWriter(path)
    try:
        conn = writer.add_topic('/' + STATE_TOPIC, 'tt_msgs/msg/BallState')
        for t_ref, e in estimates:
            msg = ball_state_message(e, t_ref, frame_id)
            ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            writer.write(conn, ns, serialize_message(msg))
    finally:
        writer.close()


def main(argv=None):
    """The command (Ctrl-C: one line, exit status 130, :func:`interruptible`)."""
    return interruptible('tt-perceive', _main, argv)


def _in_range(lo, hi, word=None):
    """argparse type: a number in [lo, hi] (the node parameter's range), or ``word`` when
    given and typed (returned as None), else a usage error naming it (exit 2)."""
    def parse(text):
        if word is not None and text == word:
            return None
        try:
            value = float(text)
        except ValueError:
            value = float('nan')
        if not lo <= value <= hi:
            also = f" or '{word}'" if word is not None else ''
            raise argparse.ArgumentTypeError(
                f'{text} is not a number in [{lo:g}, {hi:g}]{also}')
        return value
    return parse


def _main(argv=None):
    parser = argparse.ArgumentParser(
        prog='tt-perceive',
        description='Ball tracks (position, velocity, spin) from the video files or the bag of '
                    'a camera rig.')
    add_version(parser, 'tt_perception')
    parser.add_argument('--rig', required=True, help='rig file (DESIGN.md)')
    parser.add_argument('--out', required=True, help='output trajectory folder')
    parser.add_argument('--bag', help='rosbag2 bag with sensor_msgs/Image (or CompressedImage) '
                                      "on the rig's topics")
    parser.add_argument('--colour', default='any', choices=('white', 'orange', 'any'),
                        help='ball colour (default: any)')
    parser.add_argument('--model', help='model.yaml of tt-identify (default: nominal model)')
    parser.add_argument('--out-bag', help='also write the states as BallState on /ball/state '
                                          'into this new bag (MCAP)')
    parser.add_argument('--response-gamma', type=_in_range(*RESPONSE_GAMMA_RANGE), default=1.0,
                        metavar='G',
                        help="the cameras' response, pixel = 255 (light / full)^(1/G): 1 "
                             'linear (machine-vision cameras), about 2.2 for sRGB-like '
                             "webcams (perception_node's response_gamma; default 1)")
    parser.add_argument('--exposure', type=_in_range(*EXPOSURE_RANGE, word='auto'),
                        default=None, metavar='S',
                        help="the cameras' exposure time, s: the ball's motion blur "
                             "(perception_node's exposure); default auto: each camera's, "
                             "estimated from the ball's streaks in the first pass (which "
                             'tracks at 0.002) and printed')
    parser.add_argument('--image-blur', type=_in_range(*IMAGE_BLUR_RANGE, word='auto'),
                        default=None, metavar='PX',
                        help="the cameras' own blur, pixels (perception_node's image_blur: "
                             "0.6 a Bayer colour camera's demosaicing, 0 a sharp camera); "
                             "default auto: each camera's, estimated from the ball's outline "
                             'fits in a first pass over the frames and printed')
    parser.add_argument('--encoded-blur', type=_in_range(*IMAGE_BLUR_RANGE),
                        default=DetectorConfig.encoded_blur, metavar='PX',
                        help="the cameras' blur of their pixel values after the response, "
                             "pixels, with --response-gamma (perception_node's encoded_blur: "
                             f'{DetectorConfig.encoded_blur:g} JPEG q30, the default; 0 for '
                             'frames that were not compressed)')
    parser.add_argument('--any-lighting', action='store_true',
                        help="the ball may be lit from any side (perception_node's "
                             'light_from_above false; default: the lights are above the '
                             "table, the ball's top its lit side)")
    parser.add_argument('--smooth', action='store_true',
                        help="each state from all of its track's frames, the later ones too "
                             '(fixed-interval smoother; default: as perception_node publishes '
                             "it, from the frames up to it; a track's first 4 frames' carried "
                             'back from 0.1 s into it)')
    args = parser.parse_args(argv)
    out_error = output_folder_error(args.out, OUTPUT_FILE, 'tt-perceive')
    if not out_error and args.out_bag is not None:
        out_error = out_bag_error(args.out_bag, args.out)
    if out_error:
        print(f'tt-perceive: {out_error}', file=sys.stderr)
        return 2
    try:
        rig = load_rig(args.rig, min_cameras=2, need_source=True)
    except CalibrationError as exc:
        print(f'tt-perceive: {exc}', file=sys.stderr)
        return 2
    try:
        params = load_model(args.model)
    except Exception as exc:      # the model loader's own errors (file, YAML, values)
        first = one_line_reason(exc)
        named = first if first.startswith(f'{args.model}: ') else f'{args.model}: {first}'
        print(f'tt-perceive: --model {named}', file=sys.stderr)
        return 2
    try:
        detector = DetectorConfig(colour=args.colour, response_gamma=args.response_gamma,
                                  encoded_blur=args.encoded_blur,
                                  light_from_above=not args.any_lighting)
        if args.exposure is not None:
            detector.exposure = args.exposure
        if args.image_blur is not None:
            detector.image_blur = args.image_blur
        estimated = [k for k, cam in enumerate(rig.cameras)
                     if k > 0 and cam.time_offset is None and not args.bag]
        if estimated:
            for note in estimate_offsets(rig, args.colour, detector):
                print(f'tt-perceive: {note}', file=sys.stderr)

        def frames(cut):
            return bag_frames(rig, args.bag, cut) if args.bag else file_frames(rig, cut)

        tracker = TrackerConfig(smooth=args.smooth)
        if args.image_blur is None or args.exposure is None:
            pipeline, notes = pipeline_with_estimated_blurs(
                rig, frames([]), params, detector, tracker, exposure=args.exposure is None,
                image_blur=args.image_blur is None, refine=estimated)
            for note in notes:
                print(f'tt-perceive: {note}', file=sys.stderr)
        else:
            pipeline = Pipeline(rig, params=params, detector_config=detector,
                                tracker_config=tracker)
        cut = []
        estimates, errors = run(frames(cut), pipeline)
        if args.smooth:
            smoothed = pipeline.smoothed([e for _, e in estimates])
            estimates = [(t_ref, e) for (t_ref, _), e in zip(estimates, smoothed, strict=True)]
    except (InputError, OSError) as exc:
        print(f'tt-perceive: {exc}', file=sys.stderr)
        return 1
    found = [pipeline.colour_warning(), pipeline.colour_refused_warning(),
             pipeline.geometry_warning()]
    for message in [*cut, *errors.values(), *(m for m in found if m)]:
        print(f'tt-perceive: warning: {message}', file=sys.stderr)
    try:
        names = write_tracks(args.out, estimates, 'tt-perceive', args.out_bag, rig.frame_id)
    except OutputError as exc:
        print(f'tt-perceive: {exc}', file=sys.stderr)
        return 1
    print(f'tt-perceive: {len(names)} track(s), {len(estimates)} states -> {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
