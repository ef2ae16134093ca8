"""Measured-looking synthetic tracks for tests and benchmarks (no real data needed).

Balls are served from the opponent's end towards the robot (x from about +1.3 to past the
robot's end line), integrated with the model (including any effect switched on in the
parameters) at the true frame times, then degraded like a real tracker: time stamps with
jitter, Gaussian position noise, drop-outs, a few outliers of centimetres, and a track that
starts mid-air. The generator knows nothing of identification.
"""

import numpy as np

from ..ball import rollout
from .data import Track


def launch_states(n, rng):
    """n initial states (9,) of balls served towards the robot, with top/back/side spin."""
    states = np.empty((n, 9))
    for i in range(n):
        spin_y = rng.choice([-1.0, 1.0]) * rng.uniform(80.0, 300.0)   # top (-) / back (+)
        states[i] = [rng.uniform(1.1, 1.4), rng.uniform(-0.3, 0.3), rng.uniform(0.2, 0.45),
                     rng.uniform(-6.5, -4.0), rng.uniform(-0.6, 0.6), rng.uniform(-0.5, 1.5),
                     rng.uniform(-30.0, 30.0), spin_y, rng.uniform(-80.0, 80.0)]
    return states


def make_tracks(n, params, seed=0, rate=150.0, noise=0.0015, dropout=0.05, outliers=2,
                duration=0.9, spin_known=True, spin_scale=0.0, jitter=2e-4, states=None):
    """``n`` tracks of the model ``params`` as a tracker would measure them.

    The ball is sampled at the true frame times (a fixed ``rate``, Hz) and each sample is
    stamped with that time plus Gaussian jitter of std ``jitter`` (s): the stamps carry the
    error, as a camera's do. noise: position noise std (m); dropout: fraction of frames
    lost; outliers: per track, displaced by 3 to 8 cm; spin_known: store the true spin
    (divided by 1 + spin_scale, a biased spin measurement) as the track's measured spin,
    else None. ``states``: the launch states (n, 9) to use instead of random ones.
    """
    rng = np.random.default_rng(seed)
    tracks = []
    launches = launch_states(n, rng) if states is None else np.asarray(states, dtype=float)
    for i, s0 in enumerate(launches):
        times = np.arange(0.0, duration, 1.0 / rate)                # true frame times
        _, samples = rollout(s0, params, sample_times=times, stop_at_plane=False,
                             stop_at_net=False, max_bounces=2, t_max=duration)
        stamps = times + rng.normal(0.0, jitter, len(times))         # stamp jitter
        ok = np.all(np.isfinite(samples[:, :3]), axis=1) & (samples[:, 0] > -2.0)
        keep = ok & (rng.random(len(times)) > dropout)
        keep[:3] = ok[:3]
        t, p = stamps[keep], samples[keep, :3] + rng.normal(0.0, noise, (keep.sum(), 3))
        for j in rng.choice(np.arange(5, len(t)), size=min(outliers, len(t) - 5),
                            replace=False):
            direction = rng.normal(size=3)
            p[j] += rng.uniform(0.03, 0.08) * direction / np.linalg.norm(direction)
        spin = s0[6:9] / (1.0 + spin_scale) if spin_known else None
        tracks.append(Track(f'synthetic/{i:04d}', t, p, spin, 'synthetic'))
    return tracks
