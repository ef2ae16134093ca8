"""Perception on rendered scenes (two cameras at 150 fps, 640 x 480): the issue's accuracy,
spin and robustness criteria, each checked against the model's truth of the scene."""

import collections
import dataclasses
import math

import cv2
import numpy as np
import pytest
from tt_perception.detect import DetectorConfig
from tt_perception.pipeline import (
    BLOB_XY,
    XY,
    Matcher,
    Pipeline,
    Tracker,
    TrackerConfig,
    detection_row,
)
from tt_perception.triangulate import triangulate
from tt_prediction.ball import ModelParams, rollout

from tt_perception import synth

TOPSPIN_RPS = 40.0     # |w_perp| >= 30 rps, as the issue asks
FILTER_SETTLE = 0.05   # s after a track's start (and after a bounce) before velocity is judged


def run(rig, frames, colour='any', response_gamma=1.0, curvature_weight=None, image_blur=None,
        light_from_above=None, encoded_blur=None, **kwargs):
    """The pipeline over ``frames``: (estimates, errors). ``curvature_weight``,
    ``image_blur``, ``light_from_above`` and ``encoded_blur``: DetectorConfig's, its
    defaults when None."""
    given = {'curvature_weight': curvature_weight, 'image_blur': image_blur,
             'light_from_above': light_from_above, 'encoded_blur': encoded_blur}
    detector = DetectorConfig(colour=colour, response_gamma=response_gamma,
                              **{k: v for k, v in given.items() if v is not None})
    pipe = Pipeline(rig, detector_config=detector, **kwargs)
    estimates, errors = [], []
    for t, k, frame in frames:
        estimates += pipe.process(t, k, frame)
        if pipe.last_error:
            errors.append(pipe.last_error)
    return estimates + pipe.finish(), errors


def matched(estimates, truth):
    """Estimates with the true state at their time (camera 0's frames)."""
    out = []
    for e in estimates:
        i = np.searchsorted(truth['t'], e.t - 1e-9)
        if i < len(truth['t']) and abs(truth['t'][i] - e.t) < 1e-6:
            out.append((e, truth['state'][i]))
    return out


def spin_across(estimate, state):
    """The true spin across the velocity (rad/s) of ``state`` (9,), and the estimate's: its
    size over the true one's and the angle between the two, degrees."""
    u = state[3:6] / np.linalg.norm(state[3:6])
    true_perp = state[6:] - (state[6:] @ u) * u
    est_perp = estimate.state[6:] - (estimate.state[6:] @ u) * u
    true_norm, est_norm = np.linalg.norm(true_perp), np.linalg.norm(est_perp)
    cos = est_perp @ true_perp / est_norm / true_norm
    return true_norm, est_norm / true_norm, np.degrees(np.arccos(np.clip(cos, -1, 1)))


@pytest.fixture(scope='module')
def white_scene():
    rig = synth.demo_rig()
    state = synth.incoming_ball(speed=8.0, topspin_rps=TOPSPIN_RPS, sidespin_rps=10.0)
    frames, truth = synth.render_balls(rig, [state], [0.0], colour='white', duration=1.0)
    # synth's clean cameras are sharp: the detector is told so (image_blur 0).
    estimates, errors = run(rig, frames, colour='white', image_blur=0.0)
    return truth[0], estimates


def test_position_rms_within_2_mm(white_scene):
    truth, estimates = white_scene
    pairs = matched(estimates, truth)
    assert len(pairs) > 60          # the ball is in both views for ~0.55 s at 150 fps
    err = np.array([np.linalg.norm(e.state[:3] - s[:3]) for e, s in pairs])
    assert np.sqrt(np.mean(err ** 2)) <= 2e-3


def assert_velocity_within_5_cm_per_s_after_50_ms(truth, estimates, pairs):
    """Issue 15's velocity line on ``pairs`` (estimate, true state): from FILTER_SETTLE after
    the track's first state, the FILTER_SETTLE after the bounce left out (the velocity then
    depends on the spin along the incoming velocity, which flight cannot observe: the filter
    needs the same settling time after it as after the start)."""
    bounce = [ev.t for ev in truth['events'] if ev.kind == 'bounce'][0]
    start = min(e.t for e in estimates)
    judged = [(e, s) for e, s in pairs
              if e.t >= start + FILTER_SETTLE and not bounce <= e.t < bounce + FILTER_SETTLE]
    assert len(judged) > 40
    assert max(np.linalg.norm(e.state[3:6] - s[3:6]) for e, s in judged) <= 0.05


def test_velocity_within_5_cm_per_s_after_50_ms(white_scene):
    truth, estimates = white_scene
    assert_velocity_within_5_cm_per_s_after_50_ms(truth, estimates, matched(estimates, truth))


def test_one_track_and_nothing_from_the_distractor(white_scene):
    truth, estimates = white_scene
    assert {e.track_id for e in estimates} == {1}
    # Every published state is the ball's (the distractor swings 1 m away from its path).
    assert all(np.linalg.norm(e.state[:3] - s[:3]) < 0.02 for e, s in matched(estimates, truth))
    assert len(matched(estimates, truth)) == len(estimates)


def test_spin_across_velocity_after_200_ms(white_scene):
    truth, estimates = white_scene
    bounce = [ev.t for ev in truth['events'] if ev.kind == 'bounce'][0]
    start = estimates[0].t
    judged = [(e, s) for e, s in matched(estimates, truth) if start + 0.2 <= e.t < bounce]
    assert judged
    for e, s in judged:
        true_norm, ratio, angle = spin_across(e, s)
        assert true_norm >= 30 * 2 * np.pi
        assert 0.8 <= ratio <= 1.2 and angle <= 20.0


@pytest.mark.parametrize('spin', [
    {'speed': 6.0, 'topspin_rps': -35.0, 'target': (-0.5, 0.2)},                    # backspin
    {'speed': 9.0, 'sidespin_rps': 40.0, 'y0': -0.3, 'target': (-0.8, 0.3)},       # sidespin
], ids=['backspin', 'sidespin'])
def test_spin_across_velocity_for_other_spins(spin):
    rig = synth.demo_rig()
    state = synth.incoming_ball(**spin)
    frames, truth = synth.render_balls(rig, [state], [0.0], duration=0.4, lead_in=0.1)
    estimates, _ = run(rig, frames)
    bounce = [ev.t for ev in truth[0]['events'] if ev.kind == 'bounce'][0]
    judged = [(e, s) for e, s in matched(estimates, truth[0])
              if estimates[0].t + 0.2 <= e.t < bounce]
    assert judged
    for e, s in judged:
        true_norm, ratio, angle = spin_across(e, s)
        assert true_norm >= 30 * 2 * np.pi
        assert abs(ratio - 1.0) <= 0.2
        assert angle <= 20.0


def test_spin_along_velocity_unknown_until_the_bounce(white_scene):
    truth, estimates = white_scene
    bounce = [ev.t for ev in truth['events'] if ev.kind == 'bounce'][0]
    before = [e for e in estimates if e.t < bounce]
    after = [e for e in estimates if e.t > bounce + 0.1]
    assert before and after

    def sigmas(e):
        u = e.state[3:6] / np.linalg.norm(e.state[3:6])
        cov = e.covariance[6:, 6:]
        along = np.sqrt(u @ cov @ u)
        across = np.sqrt(np.trace(cov) - along ** 2) / np.sqrt(2.0)
        return along, across, e.state[6:] @ u

    late = [sigmas(e) for e in before if e.t > before[0].t + 0.2]
    # Prior 250 rad/s: across the velocity it shrinks to a few tens of rad/s; along it stays
    # large (it falls slowly only as gravity turns the velocity), and the value along the
    # velocity stays within its own uncertainty (no invented spin).
    assert all(a > 120.0 and a > 3.0 * c and abs(w) < 2.0 * a for a, c, w in late)
    assert all(sigmas(e)[0] < 60.0 for e in after)


def test_orange_ball_with_unsynchronised_cameras():
    rig = synth.demo_rig()
    state = synth.incoming_ball(speed=10.0, topspin_rps=-20.0, y0=-0.2, target=(-0.9, 0.2))
    half_frame = 0.5 / rig.fps
    frames, truth = synth.render_balls(rig, [state], [0.0], colour='orange', duration=0.7,
                                       time_offsets=[0.0, half_frame], seed=3)
    estimates, _ = run(rig, frames, colour='orange')
    pairs = matched(estimates, truth[0])
    assert len(pairs) > 40
    err = np.array([np.linalg.norm(e.state[:3] - s[:3]) for e, s in pairs])
    assert np.sqrt(np.mean(err ** 2)) <= 2e-3


def test_an_orange_ball_seen_by_monochrome_cameras_is_tracked_and_the_colour_left_unchecked():
    # A monochrome camera's frames given as BGR (mono8 converted, a grey video): the colour
    # test refused every blob of the orange ball (grey is no orange): no state, no word.
    rig = synth.demo_rig()
    state = synth.incoming_ball(speed=8.0, topspin_rps=20.0)
    frames, truth = synth.render_balls(rig, [state], [0.0], colour='orange', duration=0.45,
                                       lead_in=0.05)
    frames = list(frames)
    grey = [(t, k, cv2.cvtColor(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR))
            for t, k, f in frames]
    pipe = Pipeline(rig, detector_config=DetectorConfig(colour='orange'))
    estimates = [e for t, k, f in grey for e in pipe.process(t, k, f)]
    pairs = matched(estimates, truth[0])
    assert len(pairs) > 40
    err = np.array([np.linalg.norm(e.state[:3] - s[:3]) for e, s in pairs])
    assert np.sqrt(np.mean(err ** 2)) <= 2e-3
    assert pipe.colour_warning() == ("camera(s) cam0, cam1: grey images, so the ball colour "
                                     "'orange' is not checked there (any ball-like blob is "
                                     'taken)')
    colour = Pipeline(rig, detector_config=DetectorConfig(colour='orange'))
    for t, k, f in frames[:4]:
        colour.process(t, k, f)
    assert colour.colour_warning() is None


@pytest.mark.parametrize('frames_apart', [8, -8])
def test_a_camera_frames_out_of_step_read_frame_by_frame_keeps_every_state(frames_apart):
    # Video files are read frame n of each camera in turn: a camera whose clock is 8 frames
    # ahead of camera 0's (or behind) delivers its frame of an instant 8 frames early (late).
    # The matcher pruned the early ones by the newest time of any camera and gave up on the
    # late ones after 3 periods: 0 states (a user's two videos, one started late).
    rig = synth.demo_rig()
    state = synth.incoming_ball(speed=10.0, topspin_rps=-20.0, y0=-0.2, target=(-0.9, 0.2))
    offset = frames_apart / rig.fps
    frames, truth = synth.render_balls(rig, [state], [0.0], duration=0.7, lead_in=0.1,
                                       time_offsets=[0.0, offset], seed=3)
    frames = list(frames)
    in_step, _ = run(rig, frames)
    by_index = {}
    for t, k, frame in frames:          # on each camera's own clock: frame n at n / fps
        by_index.setdefault(k, []).append((t - (offset if k else 0.0), k, frame))
    read = [item for pair in zip(*by_index.values(), strict=False) for item in pair]
    rig.cameras[1].time_offset = -offset        # its clock minus camera 0's
    estimates, _ = run(rig, read)
    assert len(in_step) > 60
    assert len(estimates) >= len(in_step) - abs(frames_apart)
    pairs = matched(estimates, truth[0])
    assert len(pairs) == len(estimates)
    err = np.array([np.linalg.norm(e.state[:3] - s[:3]) for e, s in pairs])
    assert np.sqrt(np.mean(err ** 2)) <= 2e-3



def rolling_shutter_frames(rig, flight, readout, duration, lead_in=8):
    """Frames (t, k, BGR) of a white ball drawn by OpenCV (an anti-aliased disc at 1/16 px)
    over a grey background, as a rolling shutter sees it: each camera's rows exposed in turn
    over ``readout`` (s), the middle row at the frame's time t, so the ball is drawn where it
    was when its own row was exposed (the row found by fixed-point iteration)."""
    import independent_scene as scene
    for n in range(-lead_in, int(duration * rig.fps)):
        t = n / rig.fps
        for k, cam in enumerate(rig.cameras):
            frame = np.full((cam.height, cam.width, 3), 60, np.uint8)
            exposed = t
            for _ in range(4):
                position = flight.state([exposed])[0, :3]
                if np.isnan(position[0]):
                    break
                row = cam.project(position)[0, 1]
                exposed = t + (row / (cam.height - 1) - 0.5) * readout
            if not np.isnan(position[0]):
                u, v = cam.project(position)[0]
                radius = cam.focal * scene.RADIUS / cam.to_camera(position)[0, 2]
                cv2.circle(frame, (round(u * 16), round(v * 16)), round(radius * 16),
                           (235, 235, 235), -1, cv2.LINE_AA, shift=4)
            yield t, k, frame


@pytest.fixture(scope='module')
def rolling_flight():
    """A fast ball (14 m/s) whose image crosses the rows of camera 1 quickly."""
    import independent_scene as scene
    return scene.simulate(scene.serve(speed=14.0, topspin_rps=20.0, start=(1.5, 0.5, 0.25),
                                      target=(-0.9, -0.5)), 0.0, 0.6, max_bounces=1)


def rolling_shutter_errors(flight, drawn, told):
    """Position errors (n, 3), m, of every state, in time order, and the number of tracks,
    for frames drawn with a readout of ``drawn`` s and a rig that says ``told``."""
    rig = synth.demo_rig()
    for cam in rig.cameras:
        cam.readout_time = told
    estimates, _ = run(rig, rolling_shutter_frames(rig, flight, drawn, 0.5), colour='white',
                       image_blur=0.0)
    errors = [e.state[:3] - flight.state([e.t])[0, :3] for e in estimates]
    return np.array(errors), len({e.track_id for e in estimates})


def test_a_rolling_shutters_readout_told_places_the_ball_as_a_global_shutter_does(
        rolling_flight):
    # The rows of a rolling shutter are exposed one after another: the ball's image is where
    # the ball was when its row was read, up to half the readout (2.5 ms, 35 mm at 14 m/s)
    # from the frame's time, and the two cameras see it at different rows. The track's first
    # states too: they come from seeds seen before any track predicted the image motion.
    def rms(errors):
        return np.sqrt((errors ** 2).sum(1).mean())

    def first_states(errors):
        return np.linalg.norm(errors[:3], axis=1).max()

    readout = 5e-3        # under the frame period at 150 fps (6.7 ms)
    global_shutter, tracks = rolling_shutter_errors(rolling_flight, 0.0, 0.0)
    assert tracks == 1 and len(global_shutter) > 40
    untold, _ = rolling_shutter_errors(rolling_flight, readout, 0.0)
    told, tracks = rolling_shutter_errors(rolling_flight, readout, readout)
    assert tracks == 1 and len(told) >= len(global_shutter) - 2
    assert rms(untold) > 2e-3                   # the drawing has the effect to take out
    assert rms(told) <= rms(global_shutter) + 0.1e-3
    assert np.all(np.abs(told.mean(0)) <= 0.2e-3)
    assert first_states(told) <= first_states(global_shutter) + 0.5e-3

def test_a_camera_alone_keeps_a_bounded_backlog():
    # Camera 0 silent (unplugged), camera 1 running: its frames were kept for ever (20,000
    # frames, 20,000 entries), waiting for camera 0 to be matched past them.
    matcher = Matcher(2, 1 / 150.0)
    for n in range(20000):
        assert matcher.add(1, n / 150.0, []) == []
    # Its clock may be up to a second either way of camera 0's: that much is kept, no more.
    assert 300 < len(matcher.frames[1]) < 400


HALL_EXPOSURE = 2e-3


def hall_frames(width, height):
    """A white ball (8 m/s, 40 rps topspin, 10 rps sidespin) under synth's 'hall' imaging
    (overhead light with a highlight, contact shadow, shot noise, JPEG q30, 2 ms blur):
    (rig, frames, truth, the frames where both cameras see it)."""
    rig = synth.demo_rig(width, height)
    state = synth.incoming_ball(speed=8.0, topspin_rps=TOPSPIN_RPS, sidespin_rps=10.0)
    frames, truth = synth.render_balls(rig, [state], [0.0], colour='white', duration=1.0,
                                       imaging='hall', exposure=HALL_EXPOSURE)
    seen = synth.both_cameras_see(rig, truth[0], rendered_from=0.5 * HALL_EXPOSURE).sum()
    return rig, list(frames), truth[0], seen


def hall_run(rig, frames, truth, seen):
    """The pipeline on :func:`hall_frames`' scene: the truth, the estimates, their pairs
    with the truth and the frames seen; the track and coverage lines and position RMS
    checked (:func:`assert_one_track_in_97_percent_of_the_frames_within_1_5_mm`)."""
    estimates, _ = run(rig, frames, colour='white')
    assert_one_track_in_97_percent_of_the_frames_within_1_5_mm(estimates, truth, seen)
    return truth, estimates, matched(estimates, truth)


def assert_one_track_in_97_percent_of_the_frames_within_1_5_mm(estimates, truth, seen):
    pairs = matched(estimates, truth)
    assert {e.track_id for e in estimates} == {1} and len(pairs) == len(estimates)
    assert len({e.t for e in estimates}) == len(estimates) >= 0.97 * seen > 80
    err = np.array([e.state[:3] - s[:3] for e, s in pairs])
    assert np.sqrt(np.mean(np.sum(err ** 2, axis=1))) <= 1.5e-3


@pytest.fixture(scope='module')
def hall_scene():
    """:func:`hall_frames` at 640 x 480, rendered once for the tests below."""
    return hall_frames(640, 480)


def test_hall_light_one_track_and_no_shading_bias_beyond_a_twentieth_of_the_ball(hall_scene):
    """Under the hall's light at 640 x 480: one track through the bounce, with a state for
    >= 97 % of the frames where both cameras see the ball (the issue's coverage: the track's
    first frames too, given once it is confirmed), and the shaded underside counted in the
    centre: the mean height error stays under 2 mm, a twentieth of the ball (the lit cap's
    own centroid sits about a quarter radius, 5 mm, above the centre). Issue 15's position
    RMS (<= 1.5 mm) and spin lines (across the velocity within 20 % and 20 degrees from
    0.2 s on) hold too; its velocity line is judged at 1280 x 720 below (here the start's
    transient is 0.05 m/s at 70 ms, docs/perception.md)."""
    truth, estimates, pairs = hall_run(*hall_scene)
    err = np.array([e.state[:3] - s[:3] for e, s in pairs])
    assert abs(err[:, 2].mean()) < 2e-3
    assert_spin_across_within_20_percent_and_degrees(truth, estimates, pairs)


def assert_spin_across_within_20_percent_and_degrees(truth, estimates, pairs):
    bounce = [ev.t for ev in truth['events'] if ev.kind == 'bounce'][0]
    start = min(e.t for e in estimates)
    spins = [spin_across(e, s) for e, s in pairs if start + 0.2 <= e.t < bounce]
    assert len(spins) > 10
    for true_norm, ratio, angle in spins:
        assert true_norm >= 30 * 2 * np.pi
        assert abs(ratio - 1.0) <= 0.2 and angle <= 20.0


def test_hall_light_at_1280x720_meets_every_line_of_the_issue():
    """The same ball under the hall's light at 1280 x 720: one track, coverage >= 97 %,
    position RMS <= 1.5 mm, mean error within 0.3 mm on each axis (the highlight and the
    shaded underside move no fitted centre by more), velocity within 5 cm/s from 50 ms after
    the first state (the 50 ms after the bounce left out), spin across the velocity within
    20 % and 20 degrees from 0.2 s on. The mean's line fails without the penalty on the
    brightness's curvature (height -0.35 mm, docs/perception.md)."""
    truth, estimates, pairs = hall_run(*hall_frames(1280, 720))
    err = np.array([e.state[:3] - s[:3] for e, s in pairs])
    assert np.all(np.abs(err.mean(axis=0)) <= 0.3e-3), err.mean(axis=0)
    assert_velocity_within_5_cm_per_s_after_50_ms(truth, estimates, pairs)
    assert_spin_across_within_20_percent_and_degrees(truth, estimates, pairs)


def test_a_hall_under_flickering_lamps_keeps_its_balls_track_frame_by_frame(hall_scene):
    """Lamps on a 50 Hz mains flicker at 100 Hz: the hall's light varies 20 % either way, each
    camera (and each frame: 150 fps) caught at its own phase, the light scaled after the
    hall's imaging, as a camera with a linear response sees it. The ball keeps one track with
    a state for >= 97 % of the frames where both cameras see it, within 1.5 mm RMS (issue
    15's lines); with the background used as learnt, the table's bright parts darker or
    lighter than it gave candidates beside the ball and 19 % of the frames were lost."""
    rig, frames, truth, seen = hall_scene
    flickering = []
    for t, k, frame in frames:
        gain = 1.0 + 0.2 * math.sin(2.0 * math.pi * 100.0 * t + 1.9 * k)
        flickering.append((t, k, np.clip(frame * gain, 0, 255).round().astype(np.uint8)))
    estimates, _ = run(rig, flickering, colour='white')
    assert_one_track_in_97_percent_of_the_frames_within_1_5_mm(estimates, truth, seen)


def test_a_hall_under_lamps_on_three_phases_keeps_its_balls_track(hall_scene):
    """Three lamps along the image's width on the three phases of the mains, each
    lighting its part of the hall (blended between them), flicker 20 % either way at 100 Hz
    a third of a period apart: the whole frame's light hardly changes, each part's does.
    With each part's gain taken out of the background (detect.light_gains) the ball keeps
    one track in >= 97 % of the frames within 1.5 mm RMS; with the one gain of the frame it
    kept 95.5 % (1.10 mm RMS; lamps in three sectors around the image's centre: 84 %)."""
    rig, frames, truth, seen = hall_scene
    h, w = frames[0][2].shape[:2]
    x = np.arange(w)[None, :, None]
    lamps = [np.exp(-0.5 * ((x - c * w) / (0.2 * w)) ** 2) for c in (1 / 6, 1 / 2, 5 / 6)]
    lamps = [lamp / sum(lamps) for lamp in lamps]
    lit = []
    for t, k, frame in frames:
        gain = sum(lamp * (1.0 + 0.2 * math.sin(2.0 * math.pi * 100.0 * t + 2.094 * j + 1.9 * k))
                   for j, lamp in enumerate(lamps))
        lit.append((t, k, np.clip(frame * gain, 0, 255).round().astype(np.uint8)))
    estimates, _ = run(rig, lit, colour='white')
    assert_one_track_in_97_percent_of_the_frames_within_1_5_mm(estimates, truth, seen)


def test_a_camera_exposed_darker_still_sees_a_white_ball(hall_scene):
    """The hall at 150 fps with a short exposure: every frame at 0.35 of the light, the
    white ball's lit half at about 80 grey levels, as dark as the scene's white lines. The
    ball is judged white against those lines (its colour scaled by the camera's exposure
    level) and keeps one track in >= 97 % of the frames within 1.5 mm RMS; judged against a
    fixed least brightness of the lit half (90), every blob was refused and no state came."""
    rig, frames, truth, seen = hall_scene
    dark = [(t, k, (frame * 0.35).round().astype(np.uint8)) for t, k, frame in frames]
    estimates, _ = run(rig, dark, colour='white')
    assert_one_track_in_97_percent_of_the_frames_within_1_5_mm(estimates, truth, seen)


def test_a_frame_a_camera_delivers_twice_after_the_bounce_is_not_taken_for_its_kink(
        hall_scene):
    """A camera that delivers its last frame again (a USB camera's driver under load) 30 ms
    after the bounce: that frame's ball is a frame behind, its point 33 mm off along camera
    1's line of sight, and it fails the gate. Within ``kink_window`` of the bounce a rebound
    the model got wrong fails it too; the kink is taken only when the next point agrees, so
    the duplicate is dropped: one track in >= 97 % of the frames within 1.5 mm RMS. Taken as
    the kink on its own, its state was published 33 mm off (4.1 mm RMS)."""
    rig, frames, truth, seen = hall_scene
    bounce = [ev.t for ev in truth['events'] if ev.kind == 'bounce'][0]
    twice = [n for n, (t, k, _) in enumerate(frames) if k == 1 and t > bounce + 0.03][0]
    earlier = max(n for n, (t, k, _) in enumerate(frames[:twice]) if k == 1)
    delivered = list(frames)
    delivered[twice] = (*frames[twice][:2], frames[earlier][2])
    estimates, _ = run(rig, delivered, colour='white')
    assert_one_track_in_97_percent_of_the_frames_within_1_5_mm(estimates, truth, seen)


BALL_AT = np.array([0.5, 0.1, 0.3])


def detections_of_a_ball(rig, sure=(True, True), widths=((1.0, 1.0), (1.0, 1.0))):
    """One detection row per camera of a ball at BALL_AT, exactly where it projects:
    ``sure`` of its colour per camera, ``widths`` (silhouette, bright part) per camera in
    the ball's image diameters."""
    rows = []
    for cam, ok, (silhouette, bright) in zip(rig.cameras, sure, widths, strict=True):
        xy = cam.normalise(cam.project(BALL_AT[None]))[0]
        diameter = 2.0 * cam.focal * 0.02 / (cam.R @ BALL_AT + cam.t)[2]
        rows.append(detection_row(xy, silhouette * diameter, sure=ok,
                                  bright_width=bright * diameter))
    return [[row] for row in rows]


def test_a_point_is_sure_when_one_camera_is_sure_of_the_colour():
    """Two cameras' detections of the same ball triangulate to a point that is sure when at
    least one of them is sure of the ball's colour, and unsure when neither is (a
    washed-out blob in each view may be anything of that brightness)."""
    rig = synth.demo_rig()
    pipe = Pipeline(rig)
    sure, unsure = pipe._points(detections_of_a_ball(rig))
    assert len(sure) == 1 and not unsure and np.allclose(sure[0][0][0], BALL_AT, atol=1e-6)
    sure, unsure = pipe._points(detections_of_a_ball(rig, sure=(False, False)))
    assert not sure and len(unsure) == 1 and np.allclose(unsure[0][0][0], BALL_AT, atol=1e-6)
    assert [len(p) for p in pipe._points(detections_of_a_ball(rig, sure=(True, False)))] == [
        1, 0]


def _unsure_flight(sure_at, **config):
    """Tracker states of a ball on the model's flight (its rollout) whose points are unsure
    of the colour but at the frame indices ``sure_at``; (published states' frame indices,
    track ids). ``config``: TrackerConfig's settings."""
    tracker = Tracker(150.0, config=TrackerConfig(backfill=False, **config))
    times = np.arange(20) / 150.0
    ball = np.array([1.2, 0.1, 0.3, -6.0, 0.2, 1.0, 0.0, -150.0, 0.0])
    _, truth = rollout(ball, tracker.params, sample_times=times, stop_at_plane=False,
                       stop_at_net=False, t_max=times[-1] + 1e-6)
    cov = np.eye(3) * 1e-8
    published, ids = [], set()
    for n, (t, X) in enumerate(zip(times, truth[:, :3], strict=True)):
        tracker.advance(t)
        point = [((X, cov), (X, cov))]
        given = (tracker.add(t, point) if n in sure_at else tracker.add(t, [], point))
        published += [n] * len(given)
        ids |= {e.track_id for e in given}
    return published, ids


def test_a_track_of_points_unsure_of_the_colour_is_confirmed_once_one_is_sure():
    """A track starts and goes on from points no camera is sure of the colour of (a far
    orange ball washed out by JPEG), but its states are published only from its
    ``confirm_updates``-th update on which a camera has been sure of one of its points;
    a track none of whose points is ever sure ends after ``unsure_updates`` more updates
    without a state, and the next points start another."""
    config = TrackerConfig()
    # Frame 0 seeds, frame 1 starts the track, frames 2-4 update it: confirmed on frame 4
    # when sure from the start, or on the first sure frame after that.
    assert _unsure_flight(range(20))[0] == list(range(4, 20))
    assert _unsure_flight({7})[0] == list(range(7, 20))
    assert _unsure_flight({2})[0] == list(range(4, 20))
    # Never sure: no state; the track ends after confirm_updates + unsure_updates updates
    # (on frame 9) and the next two frames start another, which a sure point then confirms.
    end = 1 + config.confirm_updates + config.unsure_updates
    published, ids = _unsure_flight({end + 6})
    assert published == list(range(end + 6, 20)) and ids == {2}
    # A sure track waits for confirm_updates however many that is.
    assert _unsure_flight(range(20), confirm_updates=12)[0] == list(range(13, 20))


@pytest.mark.parametrize('silhouette, bright, kept', [
    (1.0, 1.0, True), (2.05, 0.6, True), (2.05, 2.05, False), (0.3, 0.3, False)])
def test_a_point_is_gated_on_the_widths_of_the_silhouette_and_of_its_bright_part(
        silhouette, bright, kept):
    """A candidate is ball-sized when its silhouette is not too narrow (``width_ratio``
    0.45) and either the silhouette or its bright part is not too wide (1.9): JPEG's ringing
    around a ball of 2-3 px radius widens the silhouette, not the bright part; an object
    whose bright part is twice the ball's width is not the ball."""
    rig = synth.demo_rig()
    rows = detections_of_a_ball(rig, widths=((silhouette, bright), (1.0, 1.0)))
    assert len(Pipeline(rig)._points(rows)[0]) == int(kept)


def test_two_balls_get_two_tracks():
    rig = synth.demo_rig()
    a = synth.incoming_ball(speed=9.0, y0=0.3, target=(-0.6, 0.3))
    b = synth.incoming_ball(speed=7.0, y0=-0.3, target=(-0.8, -0.3))
    frames, truth = synth.render_balls(rig, [a, b], [0.0, 0.8], duration=0.7, distractor=False)
    estimates, _ = run(rig, frames)
    ids = sorted({e.track_id for e in estimates})
    assert len(ids) == 2
    for track_id, tr in zip(ids, truth, strict=True):
        pairs = matched([e for e in estimates if e.track_id == track_id], tr)
        assert pairs and all(np.linalg.norm(e.state[:3] - s[:3]) < 0.01 for e, s in pairs)


def test_no_ball_no_state():
    rig = synth.demo_rig()
    frames, _ = synth.render_balls(rig, [], [], duration=1.0)
    estimates, errors = run(rig, frames)
    assert estimates == [] and errors == []


def test_one_camera_only_publishes_nothing():
    rig = synth.demo_rig()
    state = synth.incoming_ball()
    frames, _ = synth.render_balls(rig, [state], [0.0], duration=0.5, drop={1: (-1.0, 1.0)})
    estimates, errors = run(rig, frames)
    assert estimates == []
    assert errors and all(err == 'camera cam1: no frame' for err in errors)


def test_corrupt_frames_are_skipped_and_the_track_goes_on():
    rig = synth.demo_rig()
    state = synth.incoming_ball()
    frames, truth = synth.render_balls(rig, [state], [0.0], duration=0.5)
    corrupt = {0.1: np.zeros((10, 10, 3), np.uint8), 0.2: np.zeros((480, 640, 3), np.float32),
               0.3: np.zeros((480, 640, 4), np.uint8)}

    def damaged():
        for t, k, frame in frames:
            bad = [f for tc, f in corrupt.items() if k == 0 and abs(t - tc) < 1e-6]
            yield t, k, (bad[0] if bad else frame)

    estimates, errors = run(rig, damaged())
    assert any('frame 10x10, its calibration 640x480' in e for e in errors)
    assert sum('not an 8-bit grey or BGR image' in e for e in errors) == 2
    assert {e.track_id for e in estimates} == {1}
    err = [np.linalg.norm(e.state[:3] - s[:3]) for e, s in matched(estimates, truth[0])]
    assert max(err) < 0.01


def test_frames_of_another_size_than_the_calibration_are_skipped_and_said_so():
    """Image topics or a bag at 800x600 for cameras calibrated at 640x480: their pixels are
    not the calibration's, so no state comes from them and the error names both sizes (the
    first frame set the background's size and every frame was detected and triangulated
    wrong, 0 states and no word: a new user's walk-through, 29 Nov 2026)."""
    rig = synth.demo_rig()
    frames, _ = synth.render_balls(rig, [synth.incoming_ball()], [0.0], duration=0.3)
    resized = ((t, k, cv2.resize(frame, (800, 600))) for t, k, frame in frames)
    estimates, errors = run(rig, resized)
    assert estimates == []
    assert set(errors) == {f'camera cam{k}: frame 800x600, its calibration 640x480: frames of '
                           'another size are skipped' for k in (0, 1)}


def test_vanishing_camera_stops_states_and_they_resume():
    rig = synth.demo_rig()
    state = synth.incoming_ball(speed=7.0)
    gone = (0.12, 0.25)
    frames, truth = synth.render_balls(rig, [state], [0.0], duration=0.6, drop={1: gone})
    estimates, errors = run(rig, frames)
    assert 'camera cam1: no frame' in errors
    # While camera 1 is away nothing is triangulated: no new state, then states come back
    # (the same track when it came back within max_coast, else a new one) and they are right.
    assert not [e for e in estimates if gone[0] + 1e-6 < e.t < gone[1]]
    assert [e for e in estimates if e.t > gone[1]]
    err = [np.linalg.norm(e.state[:3] - s[:3]) for e, s in matched(estimates, truth[0])]
    assert max(err) < 0.01


@pytest.mark.parametrize('gap', [(0.18, 0.28), (0.30, 0.40)])
def test_a_burst_of_dropped_frame_pairs_keeps_the_balls_track(gap):
    """The live node drops frame pairs when it falls behind (make demo at a slow hour lost 299
    of 1243, in bursts): 100 ms of them in flight, or across the bounce (at 0.374 s), must not
    end the track, whose next points the filter gates after carrying the ball through the
    gap (a new track starts with no spin known: a ball so restarted was struck short). The
    states after the gap are right. With the former max_coast of 0.06 s the ball had two
    tracks."""
    rig = synth.demo_rig()
    frames, truth = synth.render_balls(rig, [synth.incoming_ball(speed=7.0)], [0.0],
                                       duration=0.6)
    kept = [(t, k, frame) for t, k, frame in frames if not gap[0] < t < gap[1]]
    estimates, errors = run(rig, kept)
    assert errors == []
    assert {e.track_id for e in estimates} == {1}
    after = [e for e in estimates if e.t > gap[1]]
    assert after and after[0].t < gap[1] + 0.02        # the first pair back is taken
    err = [np.linalg.norm(e.state[:3] - s[:3]) for e, s in matched(estimates, truth[0])]
    assert len(err) == len(estimates) and max(err) < 2e-3


def test_a_white_ball_under_a_warm_light_is_white_once_the_rig_gives_the_cameras_white():
    # A camera balanced for daylight under a warm lamp (about 3000 K): its blue and green come
    # out 0.5 and 0.8 of a white surface's red, the ball's too, and the colour test (channels
    # within 0.72 of each other) refused every blob: no state, without a word.
    rig = synth.demo_rig()
    state = synth.incoming_ball(speed=8.0, topspin_rps=TOPSPIN_RPS, sidespin_rps=10.0)
    frames, truth = synth.render_balls(rig, [state], [0.0], colour='white', duration=0.6,
                                       imaging='hall')
    frames = list(frames)
    warm = np.array([0.5, 0.8, 1.0])
    warm_frames = [(t, k, np.clip(f * warm, 0, 255).astype(np.uint8)) for t, k, f in frames]
    white_light, _ = run(rig, frames, colour='white')
    assert len(white_light) > 60
    untold = Pipeline(rig, detector_config=DetectorConfig(colour='white'))
    assert [e for t, k, f in warm_frames for e in untold.process(t, k, f)] == []
    warning = untold.colour_refused_warning()
    assert warning.startswith('no track, and camera cam0 refused ')
    b, g, r = (float(v) for v in warning.split('median B, G, R ')[1].split(')')[0].split(','))
    assert b < 0.72 * r and g > b and r > g     # the warm light's tint, named
    assert "give each camera's white_bgr in the rig" in warning
    for cam in rig.cameras:
        cam.white_bgr = tuple(warm)        # a white surface in its images, B, G, R over R
    told_pipeline = Pipeline(rig, detector_config=DetectorConfig(colour='white'))
    told = [e for t, k, f in warm_frames for e in told_pipeline.process(t, k, f)]
    assert len(told) == len(white_light) and len({e.track_id for e in told}) == 1
    assert told_pipeline.colour_refused_warning() is None
    err = np.array([np.linalg.norm(e.state[:3] - s[:3]) for e, s in matched(told, truth[0])])
    assert np.sqrt(np.mean(err ** 2)) <= 1.5e-3


@pytest.fixture(scope='module')
def webcam_scene():
    """A white ball (11 m/s, 20 rps topspin) at 1280 x 720 rendered by the tests' independent
    renderer (not synth): ceiling lamps that leave the underside dark, and a camera whose
    response is gamma 2.2 with a shoulder, like a webcam's, before JPEG q30."""
    import independent_scene as scene
    rig = synth.demo_rig(1280, 720)
    flight = scene.simulate(scene.serve(speed=11.0, topspin_rps=20.0, start=(1.5, -0.2, 0.3),
                                        target=(-0.9, -0.15)), 0.0, 0.6)
    frames, truth = scene.render_scene(rig, [flight], 'white', -0.1, 0.6)
    return rig, list(frames), truth[0], scene.Sensor().gamma


@pytest.mark.parametrize('undone', [True, False])
def test_the_cameras_response_undone_removes_the_height_bias_it_causes(webcam_scene, undone):
    """An outline pixel mixes the ball's and the table's light; a camera that encodes light
    as L^(1/2.2) mixes their values unevenly, which moves the fitted outline where only the
    lit top of the ball stands out (its underside is as dark as the table). Told the
    camera's response (response_gamma), the detector undoes it and meets the issue's limits
    (RMS <= 1.5 mm, mean error within 0.3 mm per axis); not told, the centre is fitted high,
    beyond the 0.3 mm."""
    rig, frames, truth, gamma = webcam_scene
    estimates, _ = run(rig, frames, colour='white', response_gamma=gamma if undone else 1.0)
    pairs = matched(estimates, truth)
    assert len(pairs) == len(estimates) > 50     # of ~60 frames with the ball in both views
    err = np.array([e.state[:3] - s[:3] for e, s in pairs])
    mean = err.mean(axis=0)
    if undone:
        assert np.sqrt(np.mean(np.sum(err ** 2, axis=1))) <= 1.5e-3
        assert np.all(np.abs(mean) <= 0.3e-3), mean
    else:
        assert mean[2] > 0.3e-3, mean


def small_ball_frames(sensor=None):
    """The flight of :func:`webcam_scene` at 640 x 480, where the ball is 3-7 px in radius,
    rendered by the tests' independent renderer (by default through its camera's Bayer
    mosaic and JPEG q30; ``sensor``: another of its :class:`independent_scene.Sensor`)."""
    import independent_scene as scene
    rig = synth.demo_rig(640, 480)
    flight = scene.simulate(scene.serve(speed=11.0, topspin_rps=20.0, start=(1.5, -0.2, 0.3),
                                        target=(-0.9, -0.15)), 0.0, 0.6)
    frames, truth = scene.render_scene(rig, [flight], 'white', -0.1, 0.6, sensor=sensor)
    return rig, list(frames), truth[0], scene.Sensor().gamma


@pytest.fixture(scope='module')
def small_ball_scene():
    """:func:`small_ball_frames` through the renderer's camera."""
    return small_ball_frames()


def test_small_balls_are_placed_by_the_outline_not_by_a_curved_shading(small_ball_scene):
    """On a ball a few pixels across, blurred by demosaicing and JPEG, whose shaded underside
    is as dark as the table, a free quadratic brightness lets the fitted outline slide toward
    the lit top (a second minimum of the fit 0.4 radius up, in about 40 % of the frames at
    4 px radius): the height is then millimetres off. With the default penalty on the
    brightness's curvature (``curvature_weight``) the flight meets the issue's 1.5 mm RMS,
    against 1.9 times as much without it (measured 1.35 / 2.57 mm; 1.25 / 2.34 over the
    states after a track's first four, carried back from a later estimate), both with the
    outline modelled sharp (``image_blur`` 0). What the penalty leaves then is the lean of a
    sharp outline toward the blurred lit top (height mean above 0.3 mm); with the camera's
    blur modelled (the default ``image_blur``, 0.6 px, the luma blur of a Bayer camera's
    bilinear demosaicing, which this renderer's cameras have, before JPEG) the mean is within
    the issue's 0.3 mm too.
    Modelled sharp: neither blur, the light's (``image_blur``) nor the encoded values'
    (``encoded_blur``)."""
    rig, frames, truth, gamma = small_ball_scene
    rms, mean = {}, {}
    for weight, blur in ((None, 0.0), (0.0, 0.0), (None, None)):
        estimates, _ = run(rig, frames, colour='white', response_gamma=gamma,
                           curvature_weight=weight, image_blur=blur,
                           encoded_blur=None if blur is None else 0.0)
        pairs = matched(estimates, truth)
        assert len(pairs) == len(estimates) > 50
        err = np.array([e.state[:3] - s[:3] for e, s in pairs])
        rms[weight, blur] = np.sqrt(np.mean(np.sum(err ** 2, axis=1)))
        mean[weight, blur] = err.mean(axis=0)
    assert rms[None, 0.0] <= 1.5e-3
    assert rms[0.0, 0.0] > 1.5 * rms[None, 0.0]
    assert mean[None, 0.0][2] > 0.3e-3
    assert rms[None, None] <= 1.5e-3
    assert np.all(np.abs(mean[None, None]) <= 0.3e-3), mean[None, None]


@pytest.mark.parametrize('camera, lowest, highest', [
    ('bayer_jpeg', 0.45, 0.95), ('jpeg_no_mosaic', 0.0, 0.4), ('sharp', 0.0, 0.3)])
def test_each_cameras_blur_is_estimated_on_another_renderers_balls_and_places_them(
        small_ball_scene, camera, lowest, highest):
    """tt-perceive's default (:func:`tt_perception.cli.pipeline_with_estimated_blurs`) on
    the independent renderer's small balls. Its camera blurs the light by a Bayer mosaic's
    bilinear demosaicing (0.6 px of luma) and then its encoded values by JPEG q30, which the
    fit models apart (``encoded_blur``, 0.5 px by default): each camera's blur of the light
    is found between 0.45 and 0.95 px. Through its camera without the mosaic (noise and JPEG
    only) the light is not blurred: found under 0.4 px (0.44-0.51 px, the heights 0.35-0.66
    mm low, while JPEG's blur was taken for one of the light). The same renderer's sensor
    without noise, mosaic or JPEG is sharp (each pixel the mean of its 4 x 4 rays, the
    pixel's own width that the fit models), its frames not compressed (``encoded_blur`` 0):
    found under 0.3 px, not 0.6. Each way the flight tracked with it meets the issue's
    limits (RMS <= 1.5 mm, mean within 0.3 mm per axis)."""
    import independent_scene as scene
    from tt_perception.cli import pipeline_with_estimated_blurs
    encoded = {}
    if camera == 'sharp':
        rig, frames, truth, gamma = small_ball_frames(
            scene.Sensor(noise=False, bayer=False, jpeg_quality=None))
        encoded = {'encoded_blur': 0.0}
    elif camera == 'jpeg_no_mosaic':
        rig, frames, truth, gamma = small_ball_frames(scene.Sensor(bayer=False))
    else:
        rig, frames, truth, gamma = small_ball_scene
    detector = DetectorConfig(colour='white', response_gamma=gamma, **encoded)
    pipe, notes = pipeline_with_estimated_blurs(rig, frames, detector_config=detector)
    blurs = [d.config.image_blur for d in pipe.detectors]
    assert all(lowest <= b <= highest for b in blurs), notes
    estimates = []
    for t, k, frame in frames:
        estimates += pipe.process(t, k, frame)
    pairs = matched(estimates, truth)
    assert len(pairs) == len(estimates) > 50
    err = np.array([e.state[:3] - s[:3] for e, s in pairs])
    assert np.sqrt(np.mean(np.sum(err ** 2, axis=1))) <= 1.5e-3
    assert np.all(np.abs(err.mean(axis=0)) <= 0.3e-3), err.mean(axis=0)


@pytest.fixture(scope='module')
def webcam_states(webcam_scene):
    """The pipeline's states over :func:`webcam_scene` with the defaults, the camera's
    response told: (estimates, truth)."""
    rig, frames, truth, gamma = webcam_scene
    return run(rig, frames, colour='white', response_gamma=gamma)[0], truth


def test_a_tracks_first_states_are_as_accurate_as_the_later_ones(webcam_states):
    """A track is confirmed on the blobs' own centres, and a blob's centre leans toward the
    lit top (the underside, as dark as the table, is not in the silhouette): a filter fed
    them starts millimetres high. It is fed the outline fit from its first update instead,
    searched from around the blob's centre while the prediction is rough, and its start
    from two blob centres counts for little (``blob_sigma``), so the first 50 ms of the
    track, the states of its first frames carried back from the confirming one included,
    meet the issue's RMS (1.5 mm) as the whole flight does."""
    estimates, truth = webcam_states
    pairs = matched(estimates, truth)
    start = min(e.t for e in estimates)
    first = np.array([e.state[:3] - s[:3] for e, s in pairs if e.t < start + FILTER_SETTLE])
    assert len(first) >= 5                       # 150 fps: 7 or 8 frames in 50 ms
    assert np.sqrt(np.mean(np.sum(first ** 2, axis=1))) <= 1.5e-3, first


def test_spin_across_velocity_after_200_ms_on_an_independent_scene(webcam_states):
    """Issue 15's spin line judged on a scene tt_perception.synth did not render: the
    independent renderer's flight (its own integrator, the model's Magnus coefficient) and
    imaging (lamps, mosaic, JPEG q30). From 0.2 s after the track's start until the bounce
    the spin across the velocity, learnt from the flight's curvature alone, is within 20 %
    in size and 20 degrees in direction of the renderer's (20 rps topspin, 126 rad/s)."""
    estimates, truth = webcam_states
    start = min(e.t for e in estimates)
    judged = [(e, s) for e, s in matched(estimates, truth)
              if start + 0.2 <= e.t < truth['bounces'][0]]
    assert len(judged) >= 5                      # 150 fps, the bounce 0.26 s after launch
    for e, s in judged:
        true_norm, ratio, angle = spin_across(e, s)
        assert true_norm > 0.9 * 20 * 2 * np.pi
        assert abs(ratio - 1.0) <= 0.2 and angle <= 20.0, (ratio, angle)


def test_a_small_ball_at_a_tracks_start_is_not_taken_for_one_lit_from_below():
    """An orange ball of 2.3 px radius behind JPEG q30 (independent renderer, 640 x 480, the
    far camera at launch) shows only its lit top: its shaded half is as dark as the
    background. While the track's prediction is rough the outline fit starts from several
    points, and two of its minima cost nearly the same: the true centre with the top lit,
    and a centre a radius higher whose lower half takes the same pixels, lit from below.
    Taking the cheaper one (``light_from_above`` false) put the first states up to 17 mm
    high (RMS 9.3 mm over the track's first 50 ms, the states carried back to its first
    frames from the confirming estimate included: ``backfill_after`` 0, which shows the first
    fits most). Told that the light comes from above (the default), the detector keeps the
    fit lit from above: 3.0 mm RMS and no height off by more than 4 mm (the whole flight:
    1.6 mm RMS)."""
    import independent_scene as scene
    rig = synth.demo_rig(640, 480)
    flight = scene.simulate(scene.serve(speed=8.0, topspin_rps=-30.0, target=(-0.6, 0.15)),
                            0.0, 0.15)
    frames, truth = scene.render_scene(rig, [flight], 'orange', -0.2, 0.1)
    frames = list(frames)
    first = {}
    for light_from_above in (True, False):
        estimates, _ = run(rig, frames, colour='orange', response_gamma=scene.Sensor().gamma,
                           light_from_above=light_from_above,
                           tracker_config=TrackerConfig(backfill_after=0.0))
        pairs = matched(estimates, truth[0])
        start = min(e.t for e in estimates)
        first[light_from_above] = np.array([e.state[:3] - s[:3] for e, s in pairs
                                            if e.t < start + FILTER_SETTLE])
        assert len(first[light_from_above]) >= 5
    rms = {k: np.sqrt(np.mean(np.sum(v ** 2, axis=1))) for k, v in first.items()}
    assert rms[True] <= 3.5e-3 and np.all(np.abs(first[True][:, 2]) <= 4e-3), first[True]
    assert rms[False] > 2.0 * rms[True], rms      # the scene has the two minima


def test_a_narrow_blob_weakens_its_own_centre_and_not_the_one_fitted_to_the_outline():
    """A blob narrower than the ball (its shaded underside left out of the silhouette) may
    have lost part of the ball, so its own centre counts for less: the point's covariance
    grows by (1 + narrow_weight * shortfall)^2. The outline fit models the background there
    and is not moved by what the blob lost: its point keeps the covariance of
    ``pixel_sigma``. (Weakened too, the fitted points of the independent 1280 x 720 scenes
    were given 4-13 mm for errors of 0.3 mm, and the filter took 150 ms to learn the spin.)"""
    rig = synth.demo_rig(1280, 720)
    pipe = Pipeline(rig)
    cfg, cams = pipe.config, rig.cameras
    X = np.array([0.4, 0.05, 0.25])
    shortfall = 0.3
    obs = []
    for cam in cams:
        uv = cam.project(X[None])
        depth = cam.to_camera(X[None])[0, 2]
        width = (1.0 - shortfall) * 2.0 * cam.focal * pipe.params.radius / depth
        centre = cam.normalise(uv)[0]
        blob = cam.normalise(uv + np.array([0.0, -1.5]))[0]     # leaning toward the lit top
        obs.append(detection_row(centre, width, blob_xy=blob))
    obs = np.array(obs)
    fitted = pipe._point(cams, obs[:, XY], obs)
    own = pipe._point(cams, obs[:, BLOB_XY], obs)
    _, plain, _, _ = triangulate(cams, obs[:, XY], cfg.pixel_sigma, cfg.max_reprojection)
    np.testing.assert_allclose(fitted[0], X, atol=1e-9)
    np.testing.assert_allclose(fitted[1], plain, rtol=1e-9)
    ratio = np.trace(own[1]) / np.trace(plain)
    assert ratio == pytest.approx((1.0 + cfg.narrow_weight * shortfall) ** 2, rel=0.05)


@pytest.mark.parametrize('length, height, kept', [(math.nan, 0.25, True), (1.5, 0.25, True),
                                                  (2.5, 0.25, False), (2.5, 0.03, True)])
def test_a_blob_longer_than_the_ball_beyond_its_blur_makes_no_point(length, height, kept):
    """A ball's blob is the ball stretched along its image velocity by its blur; a racket's
    disc seen at a slant is as wide as a ball two diameters across and longer still (the
    independent renderer's distractor through other rigs: docs/perception_measured.md, "Other
    rigs"). Blobs whose length beyond the tracked ball's predicted blur
    (``length_over_blur``, in diameters here) is more than ``width_ratio``'s upper bound make
    no point; NaN (no track to predict the blur) is not judged, nor a ball within a diameter
    of the table, whose blob takes in its contact shadow."""
    rig = synth.demo_rig(640, 480)
    pipe = Pipeline(rig)
    X = np.array([0.4, 0.05, height])
    obs = []
    for cam in rig.cameras:
        diameter = 2.0 * cam.focal * pipe.params.radius / cam.to_camera(X[None])[0, 2]
        obs.append(detection_row(cam.normalise(cam.project(X[None]))[0], diameter,
                                 length_over_blur=length * diameter))
    obs = np.array(obs)
    point = pipe._point(rig.cameras, obs[:, XY], obs)
    assert (point is not None) == kept
    if kept:
        np.testing.assert_allclose(point[0], X, atol=1e-9)


@pytest.mark.parametrize('backfill, after', [(True, 0.0), (False, 0.0), (True, 0.1),
                                             (True, 1.0)])
def test_a_confirmed_track_gives_its_first_frames_states(backfill, after):
    """With ``backfill_after`` 0 (perception_node's ``backfill``) the frame that confirms a
    track (its third update) gives the states of the track's seed, start and first two
    updates too, in time order, on the ball's flight (the model's own rollout, measured to
    0.1 mm); without ``backfill`` (the live node) only the confirming frame's. With
    ``backfill_after`` 0.1 s they come, and the confirmed states held back till then, with
    the first update 0.1 s from the seed, all in time order; with 1 s after the last frame
    (Tracker.finish)."""
    tracker = Tracker(150.0, config=TrackerConfig(backfill=backfill, backfill_after=after))
    times = np.arange(22) / 150.0
    ball = np.array([1.2, 0.1, 0.3, -6.0, 0.2, 1.0, 0.0, -150.0, 0.0])
    _, truth = rollout(ball, tracker.params, sample_times=times, stop_at_plane=False,
                       stop_at_net=False, t_max=times[-1] + 1e-6)
    cov = np.eye(3) * 1e-8
    given = []
    for t, X in zip(times, truth[:, :3], strict=True):
        tracker.advance(t)
        given.append(tracker.add(t, [((X, cov), (X, cov))]))
    given.append(tracker.finish())
    # Frame 0 seeds, frame 1 starts the track, frames 2-4 update it: confirmed on frame 4.
    at = {0.0: 4, 0.1: 15, 1.0: len(times)}[after] if backfill else 4
    assert given[:at] == [[]] * at
    assert [e.t for e in given[at]] == pytest.approx(times[:at + 1] if backfill
                                                     else times[4:5])
    assert [[e.t for e in g] for g in given[at + 1:]] == (
        [[t] for t in times[at + 1:]] + [[]] if at < len(times) else [])
    for e in given[at]:
        i = int(np.argmin(np.abs(times - e.t)))
        assert np.linalg.norm(e.state[:3] - truth[i, :3]) < 0.3e-3
        assert np.linalg.norm(e.state[3:6] - truth[i, 3:6]) < 0.05
        assert np.all(np.linalg.eigvalsh(e.covariance) > 0.0)


def test_a_track_that_ends_before_backfill_after_gives_what_it_held_back():
    """A confirmed track that loses its ball before ``backfill_after`` (0.1 s from its seed)
    gives its earlier frames' states and those it held back when it ends (``max_coast``
    without a point), with the next frame's add(): nothing of it is lost, in time order."""
    tracker = Tracker(150.0)
    cfg = tracker.config
    times = np.arange(40) / 150.0
    ball = np.array([1.2, 0.1, 0.3, -6.0, 0.2, 1.0, 0.0, -150.0, 0.0])
    _, truth = rollout(ball, tracker.params, sample_times=times, stop_at_plane=False,
                       stop_at_net=False, t_max=times[-1] + 1e-6)
    cov = np.eye(3) * 1e-8
    seen = 7                                   # frames 0-6: confirmed on 4 (3 updates)
    given = []
    for n, (t, X) in enumerate(zip(times, truth[:, :3], strict=True)):
        tracker.advance(t)
        given.append(tracker.add(t, [((X, cov), (X, cov))] if n < seen else []))
    assert seen / 150.0 < cfg.backfill_after
    ends = next(n for n, t in enumerate(times) if t - times[seen - 1] > cfg.max_coast)
    assert all(g == [] for n, g in enumerate(given) if n != ends)
    assert [e.t for e in given[ends]] == pytest.approx(times[:seen])
    assert not tracker.active and tracker.finish() == []


def test_a_tracks_first_states_before_a_bounce_are_carried_back_from_before_it():
    """A track that starts 40 ms before the ball bounces: its estimate 0.1 s from its seed is
    past the bounce, and the flight model has no path back across it
    (``BallFilter.earlier_state``), so its first frames' states are those carried back from
    the confirming estimate, before the bounce: every frame has its state, on the ball."""
    tracker = Tracker(150.0)
    times = np.arange(25) / 150.0
    ball = np.array([0.6, 0.05, 0.14, -5.0, 0.1, -2.5, 0.0, -100.0, 0.0])
    _, truth = rollout(ball, tracker.params, sample_times=times, stop_at_plane=False,
                       stop_at_net=False, t_max=times[-1] + 1e-6)
    bounce = times[np.argmax(np.diff(truth[:, 5]) > 1.0) + 1]
    assert 0.03 < bounce < tracker.config.backfill_after
    cov = np.eye(3) * 1e-8
    given = []
    for t, X in zip(times, truth[:, :3], strict=True):
        tracker.advance(t)
        given += tracker.add(t, [((X, cov), (X, cov))])
    given += tracker.finish()
    assert [e.t for e in given] == pytest.approx(times)
    for e, s in zip(given, truth, strict=True):
        assert np.linalg.norm(e.state[:3] - s[:3]) < 1e-3, e.t


@pytest.mark.parametrize('search_updates', [0, 1, 2, 3, 4])
def test_the_outline_search_runs_only_while_the_tracks_prediction_is_rough(search_updates):
    """Tracker.rough (the detector's ``search``, four more fits per candidate) holds from a
    track's start for ``search_updates`` updates and never once it is confirmed
    (``confirm_updates`` 3); with the default 2, not on the update that confirms it either,
    whose state is the first published and would wait for the search."""
    tracker = Tracker(150.0, config=TrackerConfig(confirm_updates=3, backfill=False,
                                                  search_updates=search_updates))
    p0, v0 = np.array([1.2, 0.1, 0.3]), np.array([-6.0, 0.2, 1.0])
    cov = np.eye(3) * 1e-6
    rough, published = [], []
    for n in range(8):
        t = n / 150.0
        rough.append(tracker.rough)              # what the frame at t is detected with
        X = p0 + v0 * t + 0.5 * tracker.gravity * t * t
        tracker.advance(t)
        published.append(bool(tracker.add(t, [((X, cov), (X, cov))])))
    # Frame 0 seeds, frame 1 starts the track (updates 0), frames 2-4 update it.
    expected = [False, False] + [u < min(search_updates, 3) for u in range(6)]
    assert rough == expected
    assert published == [False] * 4 + [True] * 4


def test_a_rebound_the_model_gets_wrong_keeps_its_track():
    """A topspin ball whose flight curves three times as much as the tracker's model says
    (its Magnus coefficient; an independent renderer used five times): the filter reads
    three times its spin from the curvature, the rebound it predicts from that spin misses
    the ball's (eqs. 1-6), and the first points after the bounce fail the gate. They are
    then taken as the observed kink (the rebound's velocity and spin made more uncertain,
    TrackerConfig.kink_velocity_noise): one track through the bounce, as the issue asks, and
    every frame from 20 to 200 ms after the bounce has a state on the ball (the track ended
    at the bounce and a second one started later: an independent renderer, 29 Nov 2026)."""
    rig = synth.demo_rig()
    flight = ModelParams(c_m=3 * ModelParams().c_m)
    state = synth.incoming_ball(speed=9.0, topspin_rps=40.0, params=flight)
    frames, truth = synth.render_balls(rig, [state], [0.0], duration=0.6, params=flight)
    frames = list(frames)
    estimates, _ = run(rig, frames)
    assert {e.track_id for e in estimates} == {1}
    bounce = truth[0]['events'][0].t
    after = [t for t in truth[0]['t'] if bounce + 0.02 < t < bounce + 0.2]
    assert {round(e.t, 6) for e in estimates} >= {round(t, 6) for t in after}
    err = [np.linalg.norm(e.state[:3] - s[:3]) for e, s in matched(estimates, truth[0])]
    assert max(err) < 0.005
    # Offline (tt-perceive --smooth) the rebound's extra noise enters at the contact: the
    # frame just after it, whose live velocity still had the predicted rebound's (1.9 m/s
    # off), is smoothed with the later ones, and the frames before the bounce keep their
    # own (without that noise the smoother put the kink into the spin before it, 1.2 mm
    # RMS; with it at the kink's frame the frame before kept 1.8 m/s).
    pipe = Pipeline(rig, detector_config=DetectorConfig(image_blur=0.0),      # sharp cameras
                    tracker_config=TrackerConfig(smooth=True))
    live = [e for t, k, frame in frames for e in pipe.process(t, k, frame)]
    pairs = matched(pipe.smoothed(live), truth[0])
    assert max(np.linalg.norm(e.state[:3] - s[:3]) for e, s in pairs) < 5e-4
    assert max(np.linalg.norm(e.state[3:6] - s[3:6]) for e, s in pairs) < 0.05


def test_a_camera_threads_prediction_from_before_a_bounce_rebounds_off_the_table():
    """perception_node's camera threads place the window and the outline from the track as
    the processing thread last left it, which on a busy machine is some frames old. From a
    state 5 mm above the table falling at 3 m/s, the ball 10 ms later has bounced: it is
    above the table and rising at about e_t times its impact speed (eq. 1), less the 0.01 s
    of gravity and drag since (not below the table, where the flight without the bounce
    would have it)."""
    params = ModelParams()
    tracker = Tracker(150.0, params)
    r = params.radius
    state = np.array([-0.5, 0.1, r + 0.005, -5.0, 0.2, -3.0, 0.0, 0.0, 0.0])
    snapshot = (0.0, state, False, True)
    position, velocity = tracker.predicted_motion(0.01, snapshot)
    impact_speed = np.sqrt(3.0 ** 2 + 2 * params.gravity * 0.005)
    assert position[2] > r
    assert 0.9 * params.e_t * impact_speed - 0.01 * params.gravity < velocity[2]
    assert velocity[2] < params.e_t * impact_speed
    # Before the contact the flight is the same as the ballistic one, within the drag.
    position, _ = tracker.predicted_motion(0.001, snapshot)
    ballistic = state[:3] + 0.001 * state[3:6] + 0.5 * tracker.gravity * 0.001 ** 2
    assert np.linalg.norm(position - ballistic) < 1e-4


def run_lagging(rig, frames, lag, colour):
    """The pipeline as perception_node's camera threads and processing thread drive it when
    the processing thread is ``lag`` frame pairs behind: each frame detected from the
    running track as it was ``lag`` pairs before, but from the track as it is while that one
    is not confirmed (the camera thread waits for it, node.FRESH_WAIT)."""
    pipe = Pipeline(rig, detector_config=DetectorConfig(colour=colour))
    snapshots = collections.deque([None], maxlen=lag + 1)
    estimates = []
    for t, k, frame in frames:
        snapshot = snapshots[0]
        if snapshot is None or not snapshot[3]:
            snapshot = pipe.tracker.snapshot()
        estimates += pipe.process(t, k, frame, pipe.detect(t, k, frame, snapshot))
        if k == len(rig.cameras) - 1:
            snapshots.append(pipe.tracker.snapshot())
    return estimates + pipe.finish()


def test_camera_threads_four_frames_behind_keep_the_track_and_its_spin():
    """The orange ball of synth's hall at 640 x 480 (the spin its flight's curvature shows
    is the hardest to read there) detected four frame pairs (27 ms) behind the processing
    thread, as on a busy 2-core machine: one track through the bounce, position RMS within
    0.1 mm of the pipeline's own with no lag, spin across the velocity within 20 % and 20
    degrees from 0.2 s on. Before (the windows' prediction ballistic, blobs' centres taken
    as the ball's at a track's start) the same lag gave 2.4 against 1.5 mm RMS and a spin
    33 % off; in make demo a ball's spin was 30 % off when it was struck."""
    rig = synth.demo_rig()
    state = synth.incoming_ball(speed=8.0, topspin_rps=TOPSPIN_RPS, sidespin_rps=10.0)
    frames, truth = synth.render_balls(rig, [state], [0.0], colour='orange', duration=1.0,
                                       imaging='hall', exposure=HALL_EXPOSURE)
    frames = list(frames)
    rms = []
    for lag in (0, 4):
        estimates = run_lagging(rig, frames, lag, 'orange')
        assert {e.track_id for e in estimates} == {1}
        pairs = matched(estimates, truth[0])
        err = np.array([e.state[:3] - s[:3] for e, s in pairs])
        rms.append(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
        assert_spin_across_within_20_percent_and_degrees(truth[0], estimates, pairs)
    assert rms[1] < rms[0] + 1e-4


def test_a_young_tracks_update_on_a_blobs_own_centre_counts_its_lean():
    """A track not confirmed yet given only a blob's own centre (no centre fitted to the
    outline: the frame was detected before the track started) takes it with the variance of
    a blob's lean toward the lit side (blob_sigma, as its seeds): a point 5 mm high moves the
    track three quarters of the way (its prediction is uncertain by about as much, from the
    two seeds' blobs), where at the point's own variance it moved all the way, and each
    such update in turn gave the track the blobs' noise: it started 25 mm and 1.5 m/s off
    (synth's hall, the orange ball)."""
    tracker = Tracker(150.0, config=TrackerConfig(backfill=False))
    p0, v0 = np.array([1.2, 0.1, 0.3]), np.array([-6.0, 0.2, 1.0])
    cov = np.eye(3) * 1e-6

    def at(t):
        return p0 + v0 * t + 0.5 * tracker.gravity * t * t

    for n in range(2):                  # a seed, then the track's start
        tracker.advance(n / 150.0)
        tracker.add(n / 150.0, [((at(n / 150.0), cov), (at(n / 150.0), cov))])
    assert tracker.active and tracker.updates == 0
    t = 2 / 150.0
    tracker.advance(t)
    predicted = tracker.filter.x[2]
    blob = (at(t) + np.array([0.0, 0.0, 0.005]), cov)
    tracker.add(t, [(blob, blob)])
    assert tracker.updates == 1
    assert 0.0 < tracker.filter.x[2] - predicted < 0.8 * 0.005


BOUNCE_TIMES = np.arange(45) / 150.0
"""Frame times of :func:`bounce_flight`, s (150 fps)."""


def bounce_flight(params):
    """A ball bouncing on the table (its rebound by the model with ``params``): the rollout's
    events and its states (n, 9) at :data:`BOUNCE_TIMES`."""
    ball = np.array([0.3, 0.1, 0.25, -6.0, 0.2, -1.0, 0.0, -100.0, 0.0])
    return rollout(ball, params, sample_times=BOUNCE_TIMES, stop_at_plane=False,
                   stop_at_net=False, t_max=BOUNCE_TIMES[-1] + 1e-6)


def track_flight(tracker, truth, off=None):
    """``truth`` (:func:`bounce_flight`) seen exactly (1 mm variance) by ``tracker`` every
    frame, the frames ``off`` (index: position offset, m) moved. Returns the states ``add``
    gave, (time, state), whether each frame updated the track, and the largest distance of
    a state from the ball, m."""
    cov = np.eye(3) * 1e-6
    states, updated = [], []
    for n, (t, X) in enumerate(zip(BOUNCE_TIMES, truth[:, :3], strict=True)):
        X = X + np.asarray((off or {}).get(n, 0.0))
        before = tracker.updates
        tracker.advance(t)
        states += [(e.t, e.state) for e in tracker.add(t, [((X, cov), (X, cov))])]
        updated.append(tracker.updates > before)
    worst = max(np.linalg.norm(x[:3] - truth[np.searchsorted(BOUNCE_TIMES, t - 1e-9), :3])
                for t, x in states)
    return states, updated, worst


def test_an_outlier_just_after_a_bounce_is_not_taken_for_the_rebounds_kink():
    """One point 40 ms after the bounce 15 mm off (a fit pulled by the table's white end
    line behind the ball): it fails the gate, within ``kink_window`` of the bounce, where a
    rebound the model got wrong would fail it too (the observed kink). A kink is taken only
    when the next point agrees with it; this one's passes the gate as predicted, so the
    outlier is dropped: it updates nothing, every other point does, and no state the track
    gives is more than 1 mm off the ball. Before, the outlier was taken as the kink on its
    own and its state was published 15 mm off (synth's hall: 37-45 mm off, a camera
    delivering a frame twice or its light stepping 30 %)."""
    tracker = Tracker(150.0, config=TrackerConfig(backfill=False))
    events, truth = bounce_flight(tracker.params)
    assert events[0].kind == 'bounce' and events[0].t < BOUNCE_TIMES[25]
    outlier = int(np.searchsorted(BOUNCE_TIMES, events[0].t + 0.04))
    states, updated, worst = track_flight(tracker, truth,
                                          off={outlier: [0.011, -0.0045, -0.0087]})
    assert tracker.track_id == 1
    assert not updated[outlier] and all(updated[outlier + 1:])
    assert BOUNCE_TIMES[outlier] not in [t for t, _ in states]
    assert worst < 1e-3


def test_a_rebound_the_model_gets_wrong_is_taken_as_the_kink_at_its_second_point():
    """A ball whose flight curves five times as much as the tracker's model says (its Magnus
    coefficient, as an independent renderer's): the filter reads the spin wrong from the
    curvature, and the rebound it predicts from that spin misses the ball's. The first point
    that fails the gate after the bounce is held; the next agrees with it under the kink's
    extra noise (``kink_velocity_noise``) and both are fused: one track, one frame whose
    update (and state) waits for the next, a state for every frame, each within 5 mm of the
    ball and in time order, and the track ends on the ball."""
    tracker = Tracker(150.0, config=TrackerConfig(backfill=False))
    events, truth = bounce_flight(dataclasses.replace(tracker.params,
                                                      c_m=5 * tracker.params.c_m))
    states, updated, worst = track_flight(tracker, truth)
    times = BOUNCE_TIMES
    missed = [n for n, u in enumerate(updated) if not u and times[n] > events[0].t]
    assert tracker.track_id == 1 and tracker.kinked is not None
    assert len(missed) == 1 and times[missed[0]] - events[0].t < TrackerConfig().kink_window
    given = [t for t, _ in states]
    assert given == sorted(given) and given == list(times[len(times) - len(given):])
    assert given[0] < events[0].t
    assert worst < 5e-3
    assert np.linalg.norm(tracker.filter.x[:3] - truth[-1, :3]) < 1e-3


@pytest.mark.parametrize('fitted, width, kept', [(True, 0.2, True), (False, 0.2, False),
                                                  (True, 0.05, False)])
def test_a_narrow_silhouette_is_refused_unless_the_centre_is_fitted_to_the_outline(
        fitted, width, kept):
    """A ball darker than the floor behind it keeps only its lit edge in the silhouette
    (pixels darker than the background in every channel are taken for a shadow): a fifth of
    its width. Its centre fitted to the ball's outline is triangulated (an independent
    renderer's grey floor: coverage 78 -> 96 % with the rebound kink), a blob's own centre that
    narrow is not (it may be a part of something else), nor a fitted one of a twentieth."""
    rig = synth.demo_rig()
    pipe = Pipeline(rig)
    X = np.array([0.6, 0.1, 0.3])
    rows = []
    for cam in rig.cameras:
        px = cam.project(X[None])[0]
        diameter = 2.0 * cam.focal * pipe.params.radius / (cam.R @ X + cam.t)[2]
        centre = cam.normalise(px[None])[0]
        blob = cam.normalise((px + [0.0, -0.4 * diameter])[None])[0] if fitted else centre
        rows.append(detection_row(centre, width * diameter, blob_xy=blob))
    obs = np.array(rows)
    point = pipe._point(rig.cameras, obs[:, XY], obs)
    if kept:
        assert np.linalg.norm(point[0] - X) < 1e-6
    else:
        assert point is None
