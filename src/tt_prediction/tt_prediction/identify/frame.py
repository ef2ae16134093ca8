"""Whether measured tracks look like they are in the table frame; one-line warnings if not.

The table frame: origin at the table centre on its surface, x along the table towards the
opponent (the robot at x < 0), z up. Data in another frame load and fit without an error
(positions are only numbers) but give a meaningless model or no hit-plane error at all, so
tt-identify and tt-predict --tracks check what physics fixes in that frame:

- gravity: a ball in flight accelerates down, along -z, by about g (drag and the Magnus
  force add a few m/s^2 either way);
- the table's surface: a ball that turns upwards (a contact) near a bounce height is on the
  table at z = ball radius; if no upward turn of any track is there, the surface is not
  at z = 0;
- the table's outline: a table bounce has the ball's centre over the table (|x| <= 1.37 m,
  |y| <= 0.7625 m), give or take a ball radius for an edge ball;
- the hitting plane: some track should cross x = hit_plane_x, on the robot's side, and an
  incoming ball crosses it moving along -x (towards the robot);
- the surface is level (after segmentation, :func:`tilt_warning`): the located bounces'
  contact heights do not rise along x or y;
- the surface is at z = 0 (after segmentation, :func:`height_warning`): the located bounces'
  contact heights are a ball radius, give or take a few millimetres.
"""

import numpy as np

from ..ball import HALF_LENGTH, HALF_WIDTH
from .segment import BOUNCE_HEIGHT

FRAME = 'the table frame (origin at the table centre on its surface, robot at x < 0, z up)'
ACC_WINDOW = 0.1
"""Length of the pieces of track whose acceleration is fitted (a parabola), s."""
AWAY_SHARE = 2.0 / 3.0
"""More than this share of the tracks crossing the hitting plane moving along +x there (away
from the robot) is warned of: a set with x turned (mpi_pam with x flipped: 48 of 50, two
tracks starting past the plane) besides one where a few tracks are returns."""
TILT_SLOPE = 5e-3
"""A slope of the bounces' contact heights over the table (m per m, 0.29 deg) warned of when
it is also TILT_SIGMAS standard errors from 0: the table is tilted in the data's frame (a
frame levelled 1 deg off puts gravity 0.17 m/s^2 along the table; the frame levelled with
the table, that is the gravity_tilt effect, and unlevelled, the model's level table meets the
bounces off their plane). Contact heights scatter by about 1 mm (mpi_launcher 0.93 mm,
mpi_pam 0.80 mm over 71 and 50 bounces; slopes 1.3 +- 0.9 and 12.7 +- 6.0 mm/m, the latter's
bounces spread over 0.1 m of x)."""
TILT_SIGMAS = 4.0
HEIGHT_OFF = 4e-3
"""The located bounces' mean contact height further than this from the ball radius (m), and
TILT_SIGMAS standard errors, is warned of: the table's surface is not at z = 0 in the data's
frame. A table 8 mm high had tt-identify select gravity_or_scale (g 10.14) without a word (a
researcher's walk-through, 7 Dec 2026), which made the replay's short leads worse; the real
sets read -0.62 +- 0.11 mm (mpi_launcher, 71 bounces) and -1.46 +- 0.12 mm (mpi_pam, 50)."""
TURN_WINDOW = 0.1
"""An upward turn: the lowest sample within this time either side, the ball at least two
radii higher on both sides within it, s."""


def _finite_sorted(t, p):
    """The finite samples of a track as read, in time order."""
    ok = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
    order = np.argsort(t[ok], kind='stable')
    return t[ok][order], p[ok][order]


def median_flight_acceleration(tracks, gravity):
    """Median acceleration (3,) of parabolas fitted to ACC_WINDOW pieces of the tracks
    ``[(t, p)]`` (a bounce or hit spoils only the pieces it falls in) in flight, m/s^2; None
    when no piece has 8 samples. In flight, whatever the frame, the ball accelerates by
    about ``gravity`` (m/s^2): a piece accelerating by less than half of it is not a flight
    (a ball rolling on the table or held; a tracker's 20 s of a ball rolling outnumbered a
    set's flights and had the set named as falling along +x)."""
    accs = []
    for t, p in tracks:
        t, p = _finite_sorted(t, p)
        start = 0
        while start < len(t):
            end = int(np.searchsorted(t, t[start] + ACC_WINDOW))
            # 8 samples at 3 times at least (stamps rounded coarser than the rate gave
            # pieces of one time, on which the fit fails).
            if end - start >= 8 and len(np.unique(t[start:end])) >= 3:
                acc = 2.0 * np.polyfit(t[start:end] - t[start], p[start:end], 2)[0]
                if np.linalg.norm(acc) > 0.5 * gravity:
                    accs.append(acc)
            start = max(end, start + 1)
    return np.median(accs, axis=0) if accs else None


def upward_turns(t, p, radius):
    """Positions (k, 3) where the ball turns upwards: the lowest sample within TURN_WINDOW
    either side, with the ball at least two radii higher on both sides within that time."""
    t, p = _finite_sorted(t, p)
    z, out = p[:, 2], []
    for i in range(1, len(t) - 1):
        lo = int(np.searchsorted(t, t[i] - TURN_WINDOW))
        hi = int(np.searchsorted(t, t[i] + TURN_WINDOW, side='right'))
        if lo == i or hi == i + 1 or z[i] > z[lo:hi].min() \
                or z[lo:i].max() < z[i] + 2 * radius \
                or z[i + 1:hi].max() < z[i] + 2 * radius:
            continue
        out.append(p[i])
    return np.array(out).reshape(-1, 3)


def frame_warnings(tracks, params, hit_plane_x, plane_option='--hit-plane-x'):
    """One-line warnings for tracks ``[(name, t, p)]`` that do not look like the table frame
    (module docstring) of a ball ``params`` (ModelParams: its radius and gravity); [] when
    they do. The median flight acceleration along z must be below -g / 2, an upward turn
    within segment.BOUNCE_HEIGHT of z = r is a table bounce."""
    radius, gravity = params.radius, params.gravity
    out = []
    n = len(tracks)
    acc = median_flight_acceleration([(t, p) for _, t, p in tracks], gravity)
    if acc is not None and acc[2] > -0.5 * gravity:
        axis = int(np.argmax(np.abs(acc)))
        down = '-+'[int(acc[axis] > 0)] + 'xyz'[axis]
        out.append(f'the balls fall along {down}, not -z: median flight acceleration '
                   f'({acc[0]:.1f}, {acc[1]:.1f}, {acc[2]:.1f}) m/s^2 where gravity gives '
                   f'about (0, 0, -{gravity:.1f}); are the tracks in {FRAME}?')
    turns = [(name, upward_turns(t, p, radius)) for name, t, p in tracks]
    turning = [(name, q) for name, q in turns if len(q)]
    z_all = np.concatenate([q[:, 2] for _, q in turning]) if turning else np.zeros(0)
    at_table = np.abs(z_all - radius) <= BOUNCE_HEIGHT
    # Three tracks are enough, or half of a smaller set: of 12 tracks measured from the floor
    # 5 turned upwards, all at 0.78 m (the rest ended before their bounce).
    if len(turning) >= min(3, max(1, n / 2)) and not at_table.any():
        out.append(f'{len(turning)} of {n} tracks turn upwards (a contact) at z = '
                   f'{np.median(z_all):.2f} m (median) and none on the table, where the ball '
                   f'centre is at z = {radius:g} m: are the tracks in {FRAME}?')
    off = []
    for name, q in turning:
        bounce = q[np.abs(q[:, 2] - radius) <= BOUNCE_HEIGHT]
        beyond = (np.abs(bounce[:, 0]) > HALF_LENGTH + radius) \
            | (np.abs(bounce[:, 1]) > HALF_WIDTH + radius)
        if beyond.any():
            off.append((name, bounce[beyond][0]))
    if off:
        name, q = off[0]
        out.append(f'{len(off)} of {n} tracks bounce at table height off the table (e.g. '
                   f'{name} at x = {q[0]:.2f} m, y = {q[1]:.2f} m; the table is |x| <= '
                   f'{HALF_LENGTH:g} m, |y| <= {HALF_WIDTH:g} m): are the tracks in {FRAME}?')
    xs = [p[np.isfinite(p[:, 0]), 0] for _, _, p in tracks]
    xs = [x for x in xs if len(x)]
    directions = [d for _, t, p in tracks
                  for d in [crossing_direction(_finite_sorted(t, p)[1], hit_plane_x)] if d]
    if xs and not directions:
        out.append(f'no track crosses the hitting plane x = {hit_plane_x:g} m (the tracks '
                   f'span x = {min(x.min() for x in xs):.2f} to {max(x.max() for x in xs):.2f}'
                   f' m): are the tracks in {FRAME}, and is {plane_option} right?')
    elif (away := sum(d > 0 for d in directions)) > AWAY_SHARE * len(directions):
        out.append(f'{away} of the {len(directions)} tracks that cross the hitting plane x = '
                   f'{hit_plane_x:g} m move along +x there, away from the robot, where an '
                   f'incoming ball moves along -x: are the tracks in {FRAME}?')
    return out


def crossing_direction(p, plane_x, span=3):
    """-1 where the ball at positions ``p`` (n, 3), m, in time order, crosses x = plane_x
    along -x at least once (a rally's track goes out before it comes in), +1 where it
    crosses only along +x, 0 where it does not cross. Each crossing's direction is that of
    the ``span`` samples either side of it (noise near the plane crosses it back and
    forth)."""
    side = np.sign(p[:, 0] - plane_x)
    change = np.flatnonzero(side[1:] != side[:-1])
    if not len(change):
        return 0
    last = len(p) - 1
    moves = p[np.minimum(change + 1 + span, last), 0] - p[np.maximum(change - span, 0), 0]
    return -1 if np.any(moves < 0.0) else 1


def tilt_warning(points):
    """One line when the bounces' contact points ``points`` (k, 3), m, table frame, lie on a
    plane tilted against z = const by more than TILT_SLOPE and TILT_SIGMAS standard errors
    (the heights fitted as a + b x + c y by least squares); None when not, or with fewer than
    6 bounces."""
    q = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(q) < 6:
        return None
    A = np.column_stack([np.ones(len(q)), q[:, 0], q[:, 1]])
    coef, _, rank, _ = np.linalg.lstsq(A, q[:, 2], rcond=None)
    if rank < 3:
        return None
    resid = q[:, 2] - A @ coef
    cov = (resid @ resid) / (len(q) - 3) * np.linalg.inv(A.T @ A)
    se = np.sqrt(np.diag(cov))
    tilted = [(coef[i], se[i], axis) for i, axis in ((1, 'x'), (2, 'y'))
              if abs(coef[i]) > TILT_SLOPE and abs(coef[i]) > TILT_SIGMAS * se[i]]
    if not tilted:
        return None
    rises = ' and '.join(f'{1e3 * b:+.1f} +- {1e3 * e:.1f} mm per m along {axis}'
                         for b, e, axis in tilted)
    angle = np.degrees(np.arctan(np.hypot(coef[1], coef[2])))
    return (f'the contact heights of the {len(q)} located bounces rise by {rises}: the '
            f'table is tilted by {angle:.2f} deg in the data frame, where the model has it '
            f'level; level the frame with the table ({FRAME}): what then remains of gravity '
            f'along the table, a table not level, is the gravity_tilt effect')


def height_warning(points, radius):
    """One line when the bounces' contact points ``points`` (k, 3), m, table frame, are on
    average more than HEIGHT_OFF and TILT_SIGMAS standard errors above or below the ball's
    centre on a table at z = 0 (``radius``, m); None when not, or with fewer than 6 bounces."""
    z = np.asarray(points, dtype=float).reshape(-1, 3)[:, 2]
    if len(z) < 6:
        return None
    off = float(np.mean(z)) - radius
    se = float(np.std(z, ddof=1)) / np.sqrt(len(z))
    if abs(off) <= HEIGHT_OFF or abs(off) <= TILT_SIGMAS * se:
        return None
    return (f"the ball's centre at the {len(z)} located bounces is {1e3 * off:+.1f} +- "
            f'{1e3 * se:.1f} mm from a ball radius ({1e3 * radius:g} mm) above z = 0: the '
            f"table's surface is at z = {1e3 * off:+.1f} mm in the data frame; shift the "
            f'positions by {-1e3 * off:+.1f} mm in z ({FRAME}), or the effects fit the '
            'offset as something else (gravity_or_scale, say)')
