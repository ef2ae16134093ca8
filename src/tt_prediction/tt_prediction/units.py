"""Plausibility of lengths given to tt (pure): positions in the table frame are metres, and a
table-tennis room is at most 20 m across, so a coordinate beyond +-10 m (or a camera 20 m
away) is almost surely in millimetres (or nonsense). The checks return the one-line reason,
or '' when the values are plausible; callers add the file and field."""

import numpy as np

ROOM_HALF_EXTENT_M = 10.0
"""Largest |x|, |y| or |z| of a ball position in the table frame, m."""
RIG_MAX_TRANSLATION_M = 20.0
"""Largest distance of a camera centre from the table origin (norm of the rig's translation),
m."""
MAX_TIME_S = 1e10
"""Largest |t| of a sample or state, s (317 years: epoch seconds pass): beyond it a double no
longer resolves the flight's microseconds (at 1e17 s, not even its seconds), so the time is
almost surely in nanoseconds or nonsense."""
MAX_SAMPLE_STEP_S = 0.1
"""Longest median step between a ball track's samples, s: a flight lasts about a second and
is tracked at tens to hundreds of Hz, so a median step of more is almost surely times in
milliseconds (or nonsense)."""


def outside_room(positions):
    """Mask (n,) of the rows of ``positions`` ((3,) or (n, 3), m) with a finite coordinate
    beyond :data:`ROOM_HALF_EXTENT_M`."""
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    return np.any(np.abs(np.where(np.isfinite(p), p, 0.0)) > ROOM_HALF_EXTENT_M, axis=1)


def position_error(positions, field='p', most=False, lines=None):
    """Why ``positions`` ((3,) or (n, 3), table frame) are not ball positions in metres, or ''.

    Parameters
    ----------
    positions : array_like
        One position (x, y, z) or rows of them, m. Non-finite values are not judged here.
    field : str
        The field's name in the input, for the message (``"p"``, ``x, y, z``).
    most : bool
        Judge a track: only when most of its finite rows are outside the room. A few wild
        samples (a stereo mismatch 12 m away) are outliers for the caller to drop
        (:func:`outside_room`), not a file in millimetres.
    lines : sequence of int or None
        The file line of each row: the row is named by its line (else by its number).

    Returns
    -------
    str
        ``'"p" = [1600, 100, 300]: outside the room (|coordinate| > 10 m): positions are in
        metres, not millimetres or centimetres'`` or ''.
    """
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    big = outside_room(p)
    if not big.any():
        return ''
    if most and 2 * big.sum() <= np.all(np.isfinite(p), axis=1).sum():
        return ''
    first = int(np.flatnonzero(big)[0])
    shown = '[' + ', '.join(f'{v:.6g}' for v in p[first]) + ']'
    where = ('' if p.shape[0] == 1 else f' (row {first + 1})' if lines is None
             else f' (line {lines[first]})')
    return (f'{field} = {shown}{where}: outside the room (|coordinate| > '
            f'{ROOM_HALF_EXTENT_M:g} m): positions are in metres, not millimetres or '
            'centimetres')


def time_error(times, field='t'):
    """Why ``times`` (a number or (n,)) are not times in seconds a flight can be integrated
    at, or '': ``'"t" = 1e+17: beyond 1e+10 s ...'`` (non-finite values are not judged)."""
    t = np.asarray(times, dtype=float).reshape(-1)
    big = np.abs(np.where(np.isfinite(t), t, 0.0)) > MAX_TIME_S
    if not big.any():
        return ''
    return (f'{field} = {t[np.flatnonzero(big)[0]]:.6g}: beyond {MAX_TIME_S:g} s, where a '
            "double no longer resolves a flight's microseconds: give seconds from a recent "
            'origin (not nanoseconds)')


def sample_time_error(times, field='t'):
    """Why ``times`` (n,), a ball track's sample times, are not in seconds, or ''.

    Judged on the median step between successive distinct finite times, against
    :data:`MAX_SAMPLE_STEP_S`: ``'t: median step between samples 5.66: a ball track is
    sampled at tens to hundreds of Hz; times are in seconds, not milliseconds'``.
    """
    t = np.asarray(times, dtype=float)
    steps = np.diff(np.unique(t[np.isfinite(t)]))
    if len(steps) == 0:
        return ''
    step = float(np.median(steps))
    if not step > MAX_SAMPLE_STEP_S:
        return ''
    return (f'{field}: median step between samples {step:.6g}: a ball track is sampled at '
            'tens to hundreds of Hz; times are in seconds, not milliseconds')


def translation_error(translation, field='translation'):
    """Why a rig camera's ``translation`` (3,) is not in metres, or ''.

    The rig stores world-to-camera (R, t); the camera centre is -R^T t, at the same distance
    |t| from the table origin, so |t| alone decides.
    """
    t = np.asarray(translation, dtype=float).reshape(3)
    dist = float(np.linalg.norm(t))
    if not dist > RIG_MAX_TRANSLATION_M:
        return ''
    shown = '[' + ', '.join(f'{v:.6g}' for v in t) + ']'
    return (f'{field} {shown} puts the camera {dist:.4g} m from the table (more than '
            f'{RIG_MAX_TRANSLATION_M:g} m): translations are in metres, not millimetres or '
            'centimetres')
