"""Speed of perception: detection + triangulation + filter update per frame pair, <= 3 ms median
on one core (so that two 300 fps cameras are kept up with).

The scene is rendered first (two 640 x 480 cameras at 150 fps, one white ball served toward the
robot with topspin, the distractor on); then every frame goes through
:class:`tt_perception.pipeline.Pipeline` and the time of the two frames of each instant is
summed. The target is held on the CPU time of this thread (``cpu_*``, ``time.thread_time``):
the work one core does, whatever other jobs take of the machine meanwhile; the wall-clock
times (``wall_*``) are reported too and include those jobs' time slices on a shared machine.
``tracked_*`` are the pairs where the ball is tracked (a search window around the prediction
in each camera); the others are every pair, including the full-frame searches before the
ball appears and after it leaves. OpenCV and BLAS are held to one thread. ``accuracy``
holds the errors of the same run against the scene's truth (no target here: the tests hold
them to the issue's limits).
"""

import sys
import time

import cv2
import numpy as np
from tt_perception.cli import pipeline_with_estimated_blurs
from tt_perception.detect import DetectorConfig
from tt_perception.pipeline import Pipeline, TrackerConfig
from tt_prediction.identify.blas import blas_threads

from tt_perception import synth

TARGET_MS = 3.0


def run():
    cv2.setNumThreads(1)
    rig = synth.demo_rig()
    state = synth.incoming_ball(speed=8.0, topspin_rps=40.0, sidespin_rps=10.0)
    frames, truth = synth.render_balls(rig, [state], [0.0], duration=0.8, lead_in=0.2)
    frames = list(frames)
    sharp = DetectorConfig(image_blur=0.0)     # synth's clean cameras do not blur
    warm = Pipeline(rig, detector_config=sharp)     # numba kernels compiled outside the timing
    for t, k, frame in frames[:120]:
        warm.process(t, k, frame)
    pipe = Pipeline(rig, detector_config=sharp)
    cpu, wall, tracked, estimates = {}, {}, {}, []
    with blas_threads(1):
        for t, k, frame in frames:
            active = pipe.tracker.active
            start_cpu, start_wall = time.thread_time(), time.perf_counter()
            estimates += pipe.process(t, k, frame)
            n = round(t * rig.fps)
            cpu[n] = cpu.get(n, 0.0) + time.thread_time() - start_cpu
            wall[n] = wall.get(n, 0.0) + time.perf_counter() - start_wall
            tracked[n] = tracked.get(n, True) and active
    cpu_ms = np.array(list(cpu.values())) * 1e3
    wall_ms = np.array(list(wall.values())) * 1e3
    tracked_ms = np.array([cpu[n] for n in cpu if tracked[n]]) * 1e3
    median = float(np.median(cpu_ms))
    return {
        'passed': bool(median <= TARGET_MS),
        'target_median_ms': TARGET_MS,
        'frame_pairs': int(cpu_ms.size),
        'cpu_median_ms': round(median, 3),
        'cpu_mean_ms': round(float(cpu_ms.mean()), 3),
        'cpu_p95_ms': round(float(np.percentile(cpu_ms, 95)), 3),
        'tracked_cpu_median_ms': round(float(np.median(tracked_ms)), 3),
        'tracked_pairs': int(tracked_ms.size),
        'wall_median_ms': round(float(np.median(wall_ms)), 3),
        'wall_p95_ms': round(float(np.percentile(wall_ms, 95)), 3),
        'image_size': [rig.cameras[0].width, rig.cameras[0].height],
        'accuracy': accuracy(estimates, truth[0]),
        'hall': hall_accuracy(),
    }


def hall_accuracy():
    """Accuracy under the hall's imaging (synth ``imaging='hall'``: overhead light with
    shading and highlight, contact shadow, vignetting, shot noise, JPEG q30, 2 ms blur), for
    both balls and both resolutions. Issue 15 asks for position RMS <= 1.5 mm and a mean error
    within +-0.3 mm on each axis, states in >= 97 % of the frames where both cameras see the
    ball (``coverage``), a velocity within 0.05 m/s from 50 ms after the first state (the
    50 ms after the bounce left out) and the spin across the velocity within 20 % and 20
    degrees from 0.2 s on (:func:`accuracy`); the numbers are reported as they are. Each
    row is the live node's states; its ``smoothed`` the same numbers for those tt-perceive
    writes by default (:meth:`tt_perception.pipeline.Pipeline.smoothed`); its
    ``estimated_blurs`` the live states with each camera's exposure and ``image_blur``
    estimated from the ball's outline fits, as tt-perceive sets them by default
    (:func:`tt_perception.cli.pipeline_with_estimated_blurs`), and the estimates."""
    out = {}
    exposure = 2e-3
    state = synth.incoming_ball(speed=8.0, topspin_rps=40.0, sidespin_rps=10.0)
    for width, height in ((640, 480), (1280, 720)):
        rig = synth.demo_rig(width, height)
        for colour in ('white', 'orange'):
            frames, truth = synth.render_balls(rig, [state], [0.0], colour=colour,
                                               duration=0.8, lead_in=0.2, imaging='hall',
                                               exposure=exposure)
            frames = list(frames)
            detector = DetectorConfig(colour=colour)
            pipe = Pipeline(rig, detector_config=detector,
                            tracker_config=TrackerConfig(smooth=True))
            estimates = []
            for t, k, frame in frames:
                estimates += pipe.process(t, k, frame)
            estimates += pipe.finish()
            # The ball is launched at 0: frames from half an exposure on show it.
            seen = int(synth.both_cameras_see(rig, truth[0],
                                              rendered_from=0.5 * exposure).sum())
            row = hall_row(estimates, truth[0], seen)
            row['smoothed'] = hall_row(pipe.smoothed(estimates), truth[0], seen)
            pipe, _ = pipeline_with_estimated_blurs(rig, frames, detector_config=detector,
                                                    exposure=True)
            estimates = []
            for t, k, frame in frames:
                estimates += pipe.process(t, k, frame)
            estimates += pipe.finish()
            row['estimated_blurs'] = hall_row(estimates, truth[0], seen)
            row['estimated_blurs']['image_blur_px'] = [
                round(d.config.image_blur, 3) for d in pipe.detectors]
            row['estimated_blurs']['exposure_ms'] = [
                round(d.config.exposure * 1e3, 3) for d in pipe.detectors]
            out[f'{colour}_{width}x{height}'] = row
    return out


def hall_row(estimates, truth, seen):
    """One row of :func:`hall_accuracy`: ``seen`` frames where both cameras see the ball."""
    estimates = sorted(estimates, key=lambda e: e.t)  # a track's first states come late
    idx = [int(np.argmin(np.abs(truth['t'] - e.t))) for e in estimates]
    err = np.array([e.state[:3] - truth['state'][i, :3]
                    for e, i in zip(estimates, idx, strict=True)]).reshape(-1, 3)
    row = {
        'states': len(estimates),
        'tracks': len({e.track_id for e in estimates}),
        'coverage': round(len(estimates) / max(seen, 1), 3),
        'position_rms_mm': round(float(np.sqrt(np.mean(np.sum(err ** 2, axis=1)))) * 1e3, 3)
        if len(err) else None,
        'mean_error_mm': [round(float(v) * 1e3, 3) for v in err.mean(axis=0)]
        if len(err) else None,
    }
    if estimates:
        motion = accuracy(estimates, truth)
        row.update({key: motion[key] for key in ('velocity_max_err_m_s', 'spin_perp_max_rel_err',
                                                 'spin_perp_max_angle_deg')})
    return row


def spin_across_errors(est, true):
    """The spin across the velocity of estimated states ``est`` (n, 9) against the true
    states ``true`` (n, 9), both [p, v, w]: its size's relative error (signed) and the angle
    between the two, degrees, each (n,); "across" is across the true velocity."""
    u = true[:, 3:6] / np.linalg.norm(true[:, 3:6], axis=1, keepdims=True)
    true_perp = true[:, 6:] - np.sum(true[:, 6:] * u, axis=1, keepdims=True) * u
    est_perp = est[:, 6:] - np.sum(est[:, 6:] * u, axis=1, keepdims=True) * u
    true_norm = np.linalg.norm(true_perp, axis=1)
    est_norm = np.linalg.norm(est_perp, axis=1)
    cos = np.sum(est_perp * true_perp, axis=1) / np.maximum(est_norm * true_norm, 1e-300)
    return est_norm / true_norm - 1.0, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def accuracy(estimates, truth):
    """Errors of the estimates against the scene's truth (for docs/perception.md)."""
    bounce = [e.t for e in truth['events'] if e.kind == 'bounce'][0]
    start = estimates[0].t
    est = np.array([e.state for e in estimates])
    true = truth['state'][[int(np.argmin(np.abs(truth['t'] - e.t))) for e in estimates]]
    u = true[:, 3:6] / np.linalg.norm(true[:, 3:6], axis=1, keepdims=True)
    r = np.column_stack([[e.t for e in estimates],
                         np.linalg.norm(est[:, :3] - true[:, :3], axis=1),
                         np.linalg.norm(est[:, 3:6] - true[:, 3:6], axis=1),
                         *spin_across_errors(est, true),
                         [np.sqrt(uk @ e.covariance[6:, 6:] @ uk)
                          for uk, e in zip(u, estimates, strict=True)]])
    settled = (r[:, 0] >= start + 0.05) & ~((r[:, 0] >= bounce) & (r[:, 0] < bounce + 0.05))
    spin = (r[:, 0] >= start + 0.2) & (r[:, 0] < bounce)
    return {
        'states': len(r),
        'position_rms_mm': round(float(np.sqrt(np.mean(r[:, 1] ** 2)) * 1e3), 3),
        'velocity_max_err_m_s': round(float(r[settled, 2].max()), 4),
        'velocity_max_err_first_50ms_after_bounce_m_s': round(float(
            r[(r[:, 0] >= bounce) & (r[:, 0] < bounce + 0.05), 2].max()), 4),
        'spin_perp_max_rel_err': round(float(np.abs(r[spin, 3]).max()), 4),
        'spin_perp_max_angle_deg': round(float(r[spin, 4].max()), 2),
        'spin_along_v_min_std_before_bounce_rad_s': round(float(
            r[r[:, 0] < bounce, 5].min()), 1),
        'spin_along_v_max_std_after_bounce_rad_s': round(float(
            r[r[:, 0] > bounce + 0.1, 5].max()), 1),
    }


if __name__ == '__main__':
    from run_all import bench_main
    sys.exit(bench_main(__file__, run))
