"""Segmentation of a measured track into free flights and table bounces.

Real tracks hold more than free flight and table bounces: outliers, gaps, a racket contact, a
ball that rolls or falls past the table's edge. Each is handled explicitly here and counted
in ``Track.notes``; what remains is a track that the model (flight + table rebounds) can
explain, with its bounces located from the data: the bounce time is where the parabolas
fitted to the samples before and after the contact meet, not the lowest sample.
"""

import dataclasses

import numpy as np

from ..ball import HALF_LENGTH, HALF_WIDTH
from .data import Track

OUTLIER_DISTANCE = 0.02
"""A sample farther than this from the time-interpolated midpoint of its neighbours is an
outlier, m (noise is ~2 mm, a bounce or a racket hit bends the path by < 1.5 cm at 150 Hz)."""
MAX_GAP = 0.15
"""A gap in the samples longer than this ends the track, s."""
BOUNCE_HEIGHT = 0.05
"""A bounce is a minimum of z lower than this above the contact height (ball centre), m."""
CONTACT_WINDOW = 0.06
"""Samples within this time of a contact are used to fit the flight on each side, s."""
HIT_TURN = 0.5
"""A contact away from the table (racket, net, hand) turns the velocity: the cosine between
the velocities fitted before and after it falls below this."""
ROLL_SAMPLES = 8
"""This many consecutive samples within ROLL_HEIGHT of the contact height is rolling."""
ROLL_HEIGHT = 0.012
"""Height band above the contact height in which a ball is taken to roll, m."""
ROLL_SPEED = 0.3
"""A located bounce with a smaller normal speed after contact is no rebound, m/s."""
MIN_DURATION = 0.2
"""Tracks shorter than this after cutting are dropped, s."""


@dataclasses.dataclass
class Bounce:
    """A table bounce located in the data: time (s), contact point (3,), velocities (3,)."""

    t: float
    p: np.ndarray
    v_in: np.ndarray
    v_out: np.ndarray


def _count(notes, key, n=1):
    if n:
        notes[key] = notes.get(key, 0) + int(n)


def drop_outliers(t, p, notes):
    """Remove samples far from the midpoint of their neighbours (interpolated in time)."""
    keep = np.ones(len(t), dtype=bool)
    for _ in range(2):
        idx = np.flatnonzero(keep)
        if len(idx) < 3:
            break
        tt, pp = t[idx], p[idx]
        w = ((tt[1:-1] - tt[:-2]) / (tt[2:] - tt[:-2]))[:, None]
        mid = (1.0 - w) * pp[:-2] + w * pp[2:]
        dist = np.linalg.norm(pp[1:-1] - mid, axis=1)
        bad = np.flatnonzero(dist > OUTLIER_DISTANCE) + 1
        # An outlier also displaces its neighbours' midpoints: drop only the local worst.
        worst = [i for i in bad if dist[i - 1] >= max(dist[max(i - 2, 0)],
                                                      dist[min(i, len(dist) - 1)])]
        if not worst:
            break
        keep[idx[worst]] = False
    _count(notes, 'outlier_samples', (~keep).sum())
    return t[keep], p[keep]


def _poly_fit(t, y, deg):
    """Least-squares polynomial coefficients (highest first), or None if too few points."""
    if len(t) < deg + 2:
        return None
    return np.polyfit(t, y, deg)


def _side_fit(t, p, sel, t_ref):
    """Quadratic z, linear x, y fits of the samples ``sel`` around t_ref; (fits, sse)."""
    ts = t[sel] - t_ref
    fits = [_poly_fit(ts, p[sel, 0], 1), _poly_fit(ts, p[sel, 1], 1), _poly_fit(ts, p[sel, 2], 2)]
    if any(f is None for f in fits):
        return None, np.inf
    sse = sum(float(np.sum((np.polyval(f, ts) - p[sel, k]) ** 2)) for k, f in enumerate(fits))
    return fits, sse


def locate_bounce(t, p, i):
    """Bounce near the z-minimum sample i: the meeting point of the two flights, or None.

    The minimum sample belongs to the side that fits it better; the bounce time is the root
    of z_before(t) - z_after(t) between the last sample before and the first after contact.
    """
    t_ref = t[i]
    near = np.abs(t - t_ref) <= CONTACT_WINDOW
    best = None
    for split in (i, i + 1):        # sample i ends the flight before, or starts the one after
        before = near & (np.arange(len(t)) < split)
        after = near & (np.arange(len(t)) >= split)
        fb, sb = _side_fit(t, p, before, t_ref)
        fa, sa = _side_fit(t, p, after, t_ref)
        if fb is None or fa is None:
            continue
        lo, hi = t[split - 1] - t_ref, t[split] - t_ref
        roots = np.roots(fb[2] - fa[2])
        roots = roots[np.isreal(roots)].real
        roots = roots[(roots >= lo - 1e-9) & (roots <= hi + 1e-9)]
        if len(roots) == 0 or (best is not None and sb + sa >= best[0]):
            continue
        tb = float(roots[0])
        pos = np.array([0.5 * (np.polyval(fb[k], tb) + np.polyval(fa[k], tb)) for k in range(2)]
                       + [np.polyval(fb[2], tb)])
        v_in = np.array([fb[0][0], fb[1][0], 2 * fb[2][0] * tb + fb[2][1]])
        v_out = np.array([fa[0][0], fa[1][0], 2 * fa[2][0] * tb + fa[2][1]])
        if v_in[2] < 0.0 < v_out[2]:
            best = (sb + sa, Bounce(t_ref + tb, pos, v_in, v_out))
    return None if best is None else best[1]


def _turn_cosines(t, p, half=6):
    """Cosine between the velocities fitted (lines over ``half`` samples) before and after
    each sample; 1 where there are too few samples. Line fits over several samples keep
    the time-stamp jitter of real trackers from looking like a contact."""
    n = len(t)
    cos = np.ones(n)
    for i in range(half, n - half + 1):
        vb = np.polyfit(t[i - half:i], p[i - half:i], 1)[0]
        va = np.polyfit(t[i:i + half], p[i:i + half], 1)[0]
        cos[i] = vb @ va / max(np.linalg.norm(vb) * np.linalg.norm(va), 1e-9)
    return cos


def segment(track, radius=0.02):
    """A copy of ``track`` cut to what the model explains, and its bounces.

    Steps, each counted in the notes: outliers; the first gap over MAX_GAP ends the track;
    a ball below the table surface ends it; a contact away from the table (racket, net: the
    velocity turns, cosine below HIT_TURN) ends it; an unresolved bounce or rolling ends it;
    so does a bounce located off the table's outline (the model's ball bounces only with its
    centre over the table: such a bounce is data in another frame, or an edge ball).
    Returns ``(track, bounces)`` or ``(None, reason)`` when too little is left.
    """
    notes = dict(track.notes)
    t, p = drop_outliers(track.t, track.p, notes)
    gaps = np.flatnonzero(np.diff(t) > MAX_GAP)
    if len(gaps):
        _count(notes, 'samples_after_gap', len(t) - gaps[0] - 1)
        t, p = t[:gaps[0] + 1], p[:gaps[0] + 1]
    below = np.flatnonzero(p[:, 2] < 0.0)
    if len(below):
        _count(notes, 'samples_below_table', len(t) - below[0])
        t, p = t[:below[0]], p[:below[0]]
    # Contacts away from the table: racket hits (direction reversal), net, hand.
    if len(t) > 12:
        cos = _turn_cosines(t, p)
        # Away from the table: no sample of either fitting window near the surface.
        z_low = np.array([p[max(i - 6, 0):i + 6, 2].min() for i in range(len(t))])
        hits = np.flatnonzero((cos < HIT_TURN) & (z_low > radius + BOUNCE_HEIGHT))
        if len(hits):
            _count(notes, 'samples_after_racket_contact', len(t) - hits[0] + 1)
            t, p = t[:hits[0] - 1], p[:hits[0] - 1]
    if len(t) < 8:
        return None, f'{len(t)} samples left after cleaning'
    bounces = []
    z = p[:, 2]
    minima = [i for i in range(1, len(t) - 1)
              if z[i] <= z[i - 1] and z[i] < z[i + 1] and z[i] < radius + BOUNCE_HEIGHT]
    end, why = len(t), 'samples_rolling'
    for i in minima:
        b = locate_bounce(t, p, i)
        if b is None or b.v_out[2] <= ROLL_SPEED:
            # No clear rebound: too few samples after the contact, or a ball that skids.
            end, why = i, 'samples_from_unresolved_bounce'
            break
        if abs(b.p[0]) > HALF_LENGTH or abs(b.p[1]) > HALF_WIDTH:
            # The model's ball would fall past the edge here: its fit would sit on the edge,
            # where the least change of the state switches the bounce on and off.
            end, why = i, 'samples_from_bounce_off_table'
            break
        bounces.append(b)
    low = z < radius + ROLL_HEIGHT
    run = np.convolve(low, np.ones(ROLL_SAMPLES, dtype=int), 'valid')
    rolling = np.flatnonzero(run == ROLL_SAMPLES)
    if len(rolling) and rolling[0] < end:
        end, why = int(rolling[0]), 'samples_rolling'
    if end < len(t):
        _count(notes, why, len(t) - end)
        t, p = t[:end], p[:end]
        bounces = [b for b in bounces if b.t < t[-1]]
    if len(t) < 8 or t[-1] - t[0] < MIN_DURATION:
        return None, f'{len(t)} samples over {np.ptp(t) if len(t) else 0.0:.3f} s left ' \
                     'after cleaning'
    out = Track(track.name, t, p, track.spin, track.label, notes, track.spin_source)
    return out, bounces
