"""A camera's pose in the ``table`` frame from the table seen in one image (solvePnP).

    python -m tt_perception.calibrate --rig RIG.yaml --camera cam0 --image IMG \\
        [--points POINTS.yaml] [--robot-end near|far]

The known points are the table's (MODEL.md frame, z = 0 on the surface): the four corners,
the ends of the centre line, the net's ends on the side lines and the tops of the net posts
(:data:`TABLE_POINTS`). ``--points`` gives their pixels by name (a YAML mapping, e.g.
``robot_left: [102.5, 388.0]``, any 4 or more of them); without it the four corners are found
in the image as the largest four-sided outline of the white edge lines. The rectangle's
corners look the same turned by 180 degrees: the solution kept is the one whose robot end
(x = -1.37) is nearer the camera (``--robot-end near``, a camera behind the robot) or farther
(``far``). The pose is solved with SQPnP, refined by Levenberg-Marquardt, checked (RMS
reprojection error at most ``--max-error`` pixels, camera above the table) and written into the
rig file (that camera's rotation and translation only: the file's comments and other entries
are kept); the command prints the pose and the error. Errors: one line; exit status 2 for bad
arguments or input files (rig, camera, image, points), 1 when no pose is found or it does not
fit.
"""

import argparse
import itertools
import math
import sys

import cv2
import numpy as np
from tt_prediction.ball import HALF_LENGTH, HALF_WIDTH, NET_HALF_WIDTH, NET_HEIGHT
from tt_ros.errors import one_line_reason

from .camera import CalibrationError, file_error, load_rig, read_yaml, set_camera_pose

L, W = HALF_LENGTH, HALF_WIDTH
TABLE_POINTS = {
    'robot_left': (-L, W, 0.0), 'robot_right': (-L, -W, 0.0),
    'opponent_left': (L, W, 0.0), 'opponent_right': (L, -W, 0.0),
    'robot_centre': (-L, 0.0, 0.0), 'opponent_centre': (L, 0.0, 0.0),
    'net_left': (0.0, W, 0.0), 'net_right': (0.0, -W, 0.0),
    'net_post_left_top': (0.0, NET_HALF_WIDTH, NET_HEIGHT),
    'net_post_right_top': (0.0, -NET_HALF_WIDTH, NET_HEIGHT),
}
"""Known points of the table, table frame, m ('left' is +y, as seen from the robot's end)."""
CORNERS = ('robot_left', 'opponent_left', 'opponent_right', 'robot_right')


def solve_pose(camera, object_points, image_points):
    """Rotation R (3, 3), translation t (3,) and RMS reprojection error (pixels) of a camera
    from >= 4 known table points (n, 3) and their distorted pixels (n, 2)."""
    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(image_points, dtype=np.float64).reshape(-1, 1, 2)
    if len(obj) < 4:
        raise CalibrationError(f'{len(obj)} points: the pose needs 4 or more')
    ok, rvec, tvec = cv2.solvePnP(obj, img, camera.K, camera.dist, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise CalibrationError('solvePnP found no pose for these points')
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, camera.K, camera.dist, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, camera.K, camera.dist)
    rms = float(np.sqrt(np.mean(np.sum((proj - img).reshape(-1, 2) ** 2, axis=1))))
    return cv2.Rodrigues(rvec)[0], tvec.ravel(), rms


def find_table_corners(image):
    """Pixels (4, 2) of the table's corners in a BGR image: the convex four-sided outline of
    the bright edge lines, in cyclic order. None if not found (the whole table must be seen)."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    _, bright = cv2.threshold(grey, 150, 255, cv2.THRESH_BINARY)
    bright = cv2.morphologyEx(bright, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    contours, _ = cv2.findContours(bright, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    # The net cuts the outline in two: the hull of every long line piece is the table's.
    long = [c for c in contours if cv2.arcLength(c, False) > 0.05 * sum(grey.shape)]
    if not long:
        return None
    hull = cv2.convexHull(np.vstack(long))
    if cv2.contourArea(hull) < 0.01 * grey.size:
        return None
    quad = cv2.approxPolyDP(hull, 0.02 * cv2.arcLength(hull, True), True)
    if len(quad) > 4:
        quad = _quad_on_lines(quad.reshape(-1, 2), bright)
    if quad is None or len(quad) != 4:
        return None
    # Sub-pixel: refine each corner on the grey image.
    refined = cv2.cornerSubPix(grey, quad.astype(np.float32).reshape(-1, 1, 2), (5, 5),
                               (-1, -1), (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT,
                                          30, 0.01))
    return refined.reshape(4, 2).astype(float)


def _quad_on_lines(vertices, bright):
    """The four of a convex outline's ``vertices`` (n, 2, cyclic) whose quadrilateral runs
    along the bright lines ``bright`` (a binary image) the most, in cyclic order, when at
    least :data:`QUAD_ON_LINES` of its perimeter does; else None. The table's edges are its
    white edge lines; the net's white top tape reaches 15 cm past each side line, and the
    outline's edges to its ends cross the air: its six-sided outline found no table (a new
    user's walk-through, 6 Dec 2026)."""
    # Within 0.3 % of the image's width + height of a line: a lens's distortion bends the
    # edge lines away from the straight sides between the corners by a few pixels.
    k = 2 * round(0.003 * sum(bright.shape)) + 1
    near = cv2.dilate(bright, np.ones((k, k), np.uint8)) > 0
    best, best_share = None, 0.0
    for idx in itertools.combinations(range(len(vertices)), 4):
        quad = vertices[list(idx)].astype(float)
        on = total = 0
        for a, b in zip(quad, np.roll(quad, -1, axis=0), strict=True):
            n = max(int(np.hypot(*(b - a))), 2)
            u, v = np.round(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)).astype(int).T
            inside = (u >= 0) & (u < near.shape[1]) & (v >= 0) & (v < near.shape[0])
            on += int(near[v[inside], u[inside]].sum())
            total += n
        if on / total > best_share:
            best, best_share = vertices[list(idx)], on / total
    return best.reshape(4, 1, 2) if best_share >= QUAD_ON_LINES else None


QUAD_ON_LINES = 0.9
"""Least part of the table's outline found that must run along the bright edge lines."""


def pose_from_corners(camera, corners, robot_end=None):
    """Pose (R, t, rms) from the 4 corner pixels in cyclic order, trying every assignment to
    the table's corners and keeping the best that places the robot end as asked (``'near'``
    or ``'far'``; None: near, unless the camera stands beside the table, where the corners
    cannot tell the ends apart: CalibrationError)."""
    obj = np.array([TABLE_POINTS[name] for name in CORNERS])
    best = None
    for shift in range(4):
        for order in (1, -1):
            idx = [(shift + order * i) % 4 for i in range(4)]
            try:
                R, t, rms = solve_pose(camera, obj, corners[idx])
            except (CalibrationError, cv2.error):
                continue
            centre = -R.T @ t
            if centre[2] <= 0:
                continue
            robot_near = abs(centre[0] + L) < abs(centre[0] - L)
            if robot_near != (robot_end in (None, 'near')):
                continue
            if best is None or rms < best[2]:
                best = (R, t, rms)
    if best is None:
        raise CalibrationError('no pose of the table fits the corners found')
    x = float(-(best[0].T @ best[1])[0])
    if robot_end is None and abs(x) < L:
        # The other candidate is the same pose turned 180 degrees about the table's centre:
        # beside the table both fit alike, and 'near' picked one without a word (a side
        # camera written 5.8 m off; a new user's walk-through, 6 Dec 2026).
        raise CalibrationError(f'the camera stands beside the table (x = {x:.2f} m or '
                               f'{-x:.2f} m), where the corners cannot tell which end is the '
                               "robot's: give --robot-end near|far, or --points by name")
    return best


EDGE_PX = 2.0
"""A table corner found this close to the image's border (px) is where the view ends."""
SWAPS = {'left and right': ('left', 'right'),
         "the robot's and the opponent's ends": ('robot', 'opponent')}
"""Names a user may swap in ``--points``: the two words each pair exchanges."""


def _swap_that_fits(camera, names, pixels, max_error):
    """Which of :data:`SWAPS` makes the points ``names`` at ``pixels`` fit the table within
    ``max_error`` px with the camera above it, or ''. With the net posts' tops among them,
    points named as in a mirror were only 'do not fit' (a walk-through, 6 Dec 2026)."""
    for what, (a, b) in SWAPS.items():
        renamed = [n.replace(a, '\0').replace(b, a).replace('\0', b) for n in names]
        try:
            R, t, rms = solve_pose(camera, [TABLE_POINTS[n] for n in renamed], pixels)
        except (CalibrationError, cv2.error):
            continue
        if rms <= max_error and (-R.T @ t)[2] > 0.0:
            return what
    return ''


def read_points(path):
    """The pixels of known table points in the YAML file ``path`` given as ``--points``:
    (names, pixels (n, 2)); raises CalibrationError naming the file."""
    marks = read_yaml(path, '--points')
    unknown = sorted(str(n) for n in set(marks) - set(TABLE_POINTS))
    if unknown:
        raise CalibrationError(f'--points {path}: unknown point names {unknown} '
                               f'(known: {sorted(TABLE_POINTS)})')
    names = sorted(marks)
    for name in names:
        uv = marks[name]
        if not (isinstance(uv, list) and len(uv) == 2
                and all(isinstance(c, (int, float)) and not isinstance(c, bool)
                        and math.isfinite(c) for c in uv)):
            raise CalibrationError(f'--points {path}: {name} must be [u, v], two finite '
                                   f'pixel numbers, got {uv!r}')
    if len(names) < 4:
        raise CalibrationError(f'--points {path}: {len(names)} point(s); the pose needs 4 '
                               'or more')
    return names, np.array([marks[n] for n in names], dtype=float)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m tt_perception.calibrate',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--rig', required=True, help='rig file to update')
    parser.add_argument('--camera', required=True, help='camera name in the rig')
    parser.add_argument('--image', required=True, help='image of the table from that camera')
    parser.add_argument('--points', help='YAML of known point names -> [u, v] pixels')
    parser.add_argument('--robot-end', choices=('near', 'far'),
                        help='whether the robot end of the table is the nearer one (default: '
                             'near; required for a camera beside the table)')
    parser.add_argument('--max-error', type=float, default=3.0,
                        help='largest accepted RMS reprojection error, pixels (default: '
                             '%(default)s)')
    args = parser.parse_args(argv)
    try:                          # the arguments and input files: exit 2
        if not (math.isfinite(args.max_error) and args.max_error > 0.0):
            raise CalibrationError(f'--max-error must be a positive number of pixels, got '
                                   f'{args.max_error:g}')
        rig = load_rig(args.rig, min_baseline=0.0)   # the poses may be placeholders, all alike
        index = next((i for i, c in enumerate(rig.cameras) if c.name == args.camera), None)
        if index is None:
            raise CalibrationError(f'rig {args.rig}: no camera named {args.camera!r}')
        cam = rig.cameras[index]
        # Checked first: OpenCV warns on stderr about a file it cannot open.
        error = file_error('--image', args.image)
        if error:
            raise CalibrationError(error)
        image = cv2.imread(args.image, cv2.IMREAD_COLOR)
        if image is None:
            raise CalibrationError(f'--image {args.image}: not a readable image')
        if image.shape[:2] != (cam.height, cam.width):
            raise CalibrationError(f'--image {args.image}: {image.shape[1]}x{image.shape[0]} '
                                   f'but {cam.name} is calibrated at {cam.width}x{cam.height}')
        marks = read_points(args.points) if args.points else None
    except (CalibrationError, OSError, ValueError, TypeError) as exc:
        print(f'tt_perception.calibrate: {exc}', file=sys.stderr)
        return 2
    try:                          # no pose found, or one that does not fit: exit 1
        if marks is not None:
            names, pixels = marks
            R, t, rms = solve_pose(cam, [TABLE_POINTS[n] for n in names], pixels)
        else:
            corners = find_table_corners(image)
            if corners is None:
                raise CalibrationError(f'{args.image}: the table outline was not found; '
                                       'give the points with --points')
            h, w = image.shape[:2]
            if np.any((corners < EDGE_PX) | (corners > np.array([w, h]) - 1 - EDGE_PX)):
                # A corner on the image's edge is where the view ends, not the table's.
                raise CalibrationError(f"{args.image}: the table's outline reaches the "
                                       "image's edge: the table is not wholly in view; give "
                                       'the points you see with --points')
            R, t, rms = pose_from_corners(cam, corners, args.robot_end)
        if rms > args.max_error:
            swapped = _swap_that_fits(cam, *marks, args.max_error) if marks else ''
            raise CalibrationError(f'reprojection error {rms:.2f} px exceeds {args.max_error} '
                                   'px: the points do not fit the table'
                                   + (f'; they do with {swapped} swapped' if swapped else ''))
        height = float((-R.T @ t)[2])
        if height <= 0.0:
            # Points on the table's plane named as in a mirror fit exactly a camera mirrored
            # below it (a walk-through, 6 Dec 2026: exit 0, then no track).
            raise CalibrationError(f'the camera comes out {-height:.2f} m below the table: '
                                   'the points are named as in a mirror (left and right, or '
                                   "robot's and opponent's end, swapped?)")
        set_camera_pose(args.rig, index, R, t)
    except (CalibrationError, OSError, ValueError, cv2.error) as exc:
        print(f'tt_perception.calibrate: {one_line_reason(exc)}', file=sys.stderr)
        return 1
    centre = -R.T @ t
    # Four points fix the six unknowns of a pose with two to spare: a corner found 2 px off
    # still fits within 0.05 px, with the camera 3 cm off (a new user's walk-through).
    weak = (' (4 points: their RMS hardly checks the pose; --points with the net posts or '
            'the centre line does)' if (marks is None or len(marks[0]) == 4) else '')
    print(f'{cam.name}: camera at ({centre[0]:.3f}, {centre[1]:.3f}, {centre[2]:.3f}) m, '
          f'reprojection RMS {rms:.2f} px{weak}; written to {args.rig}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
