"""Incoming balls for the demo recording and the end-to-end tests, with their true flight.

Pure module (no rclpy). States are 9-vectors ``[p, v, w]`` in the ``table`` frame (m, m/s,
rad/s, MODEL.md); times are seconds from the start of the recording.
"""

from dataclasses import dataclass

import numpy as np
from tt_prediction.ball import ModelParams, rollout, zone_of
from tt_prediction.predict import predict
from tt_strike.solver import forward


@dataclass
class Ball:
    """One incoming ball: launch time (s) and launch state ``[p, v, w]``."""

    launch_time: float
    launch_state: np.ndarray


@dataclass
class Truth:
    """The true flight of a ball, as the model flies it, from launch to the hitting plane."""

    ball: Ball
    bounce_time: float
    bounce_point: np.ndarray
    bounce_zone: int
    bounce_half: int
    hit_time: float
    hit_state: np.ndarray

    def state_at(self, t, params):
        """True state(s) at absolute time(s) ``t`` (NaN outside launch..hit), shape (k, 9)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        _, samples = rollout(self.ball.launch_state, params, t0=self.ball.launch_time,
                             t_max=self.hit_time + 0.01,
                             max_bounces=2, sample_times=t)
        samples[(t < self.ball.launch_time) | (t > self.hit_time)] = np.nan
        return samples


def fly(ball, params, hit_plane_x):
    """True flight of ``ball`` to the plane ``x = hit_plane_x``; None unless the prediction
    says ``ok`` (exactly one bounce, on the robot's half, then the plane)."""
    pred = predict(ball.launch_state, params, t0=ball.launch_time, hit_plane_x=hit_plane_x)
    if pred.status != 'ok':
        return None
    bounce, hit = pred.bounce, pred.hit
    return Truth(ball, bounce.t, np.asarray(bounce.p, dtype=float), bounce.zone, bounce.half,
                 hit.t, hit.state)


def demo_balls(count, hit_plane_x=-1.5, seed=7, gap=0.4, min_hit_height=0.1, params=None):
    """``count`` served balls, one after another with ``gap`` s between a hit and the next
    launch, each flying over the net, bouncing once on the robot's half and reaching the plane
    at least ``min_hit_height`` (m) above the table's surface.

    Launches are from above the opponent's end line (x 1.5..1.7 m, z 0.25..0.40 m) at
    4.5..6.5 m/s towards the robot, with topspin, backspin or sidespin up to 150 rad/s
    (about 1400 rpm), drawn from a seeded generator so every run sees the same balls.
    """
    params = params or ModelParams()
    rng = np.random.default_rng(seed)
    truths, t = [], 0.1
    for _ in range(100 * count):
        if len(truths) == count:
            break
        p = [rng.uniform(1.5, 1.7), rng.uniform(-0.35, 0.35), rng.uniform(0.25, 0.40)]
        speed = rng.uniform(4.5, 6.5)
        target = [rng.uniform(-1.1, -0.3), rng.uniform(-0.5, 0.5)]
        heading = np.array([target[0] - p[0], target[1] - p[1]])
        heading /= np.linalg.norm(heading)
        v = [speed * heading[0], speed * heading[1], rng.uniform(1.3, 2.4)]
        kind = rng.integers(3)
        spin_rate = rng.uniform(60.0, 150.0)
        w = [[0.0, -spin_rate, 0.0], [0.0, spin_rate, 0.0], [0.0, 0.0, spin_rate]][kind]
        truth = fly(Ball(t, np.array(p + v + w, dtype=float)), params, hit_plane_x)
        if truth is None or truth.hit_state[2] < min_hit_height:
            continue
        truths.append(truth)
        t = truth.hit_time + gap
    if len(truths) < count:
        raise RuntimeError(f'only {len(truths)} of {count} balls reach x = {hit_plane_x} m')
    return truths


def landing_after_stroke(hit_state, hit_time, racket_normal, racket_velocity, params,
                         path_points=0):
    """Where a ball hit with this racket really lands (tt_strike's forward model: eq. 7, then
    the flight with the net): ``(point, zone, half, path)``, point None and zone, half 0 if it
    hits the net or misses the table; ``path`` holds ``path_points`` ball centres from the hit
    to the landing (empty when 0 or when it does not land)."""
    stroke = forward(hit_state, racket_normal, racket_velocity, params)
    point = stroke['landing']
    if point is None:
        return None, 0, 0, np.empty((0, 3))
    zone, half = zone_of(point[0], point[1])
    path = np.empty((0, 3))
    if path_points:
        state = np.concatenate([hit_state[:3], stroke['v_out'], stroke['w_out']])
        t_land = hit_time + stroke['flight_time']
        _, samples = rollout(state, params, t0=hit_time, t_max=t_land, max_bounces=1,
                             sample_times=np.linspace(hit_time, t_land, path_points))
        path = samples[np.isfinite(samples[:, 0]), :3]
    return point, zone, half, path
