"""tt-perceive over rendered video files and over a bag of sensor_msgs/Image (DESIGN.md
contract: one CSV per track, columns t,x,y,z,vx,vy,vz,wx,wy,wz)."""

import csv
import errno
import os
import pathlib
import stat

import cv2
import numpy as np
import pytest
from test_sources import overwrite_avi_frame
from tt_perception.camera import load_rig
import yaml

from tt_perception import cli, synth

HEADER = ['t', 'x', 'y', 'z', 'vx', 'vy', 'vz', 'wx', 'wy', 'wz']
LEAD_IN = 0.1


@pytest.fixture(scope='module')
def scene(tmp_path_factory):
    base = tmp_path_factory.mktemp('scene')
    rig_path = synth.make_rig(str(base / 'calib'))
    rig = load_rig(rig_path)
    state = synth.incoming_ball(speed=8.0, topspin_rps=30.0)
    frames, truth = synth.render_balls(rig, [state], [0.0], duration=0.5, lead_in=LEAD_IN)
    frames = list(frames)
    return base, rig_path, frames, truth[0]


def read_track(path):
    with open(path, newline='') as f:
        rows = list(csv.reader(f))
    assert rows[0] == HEADER
    return np.array(rows[1:], dtype=float)


def assert_matches_truth(rows, truth, t_shift):
    t = rows[:, 0] + t_shift
    idx = np.array([int(np.argmin(np.abs(truth['t'] - ti))) for ti in t])
    assert np.abs(truth['t'][idx] - t).max() < 1e-5
    err = np.linalg.norm(rows[:, 1:4] - truth['state'][idx, :3], axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 2e-3 and len(rows) > 40


@pytest.mark.parametrize('fmt', ['avi', 'png'])
def test_video_files_give_one_track(scene, tmp_path, capsys, fmt):
    base, rig_path, frames, truth = scene
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, [truth], fmt=fmt)
    out = tmp_path / 'out'
    assert cli.main(['--rig', video_rig, '--out', str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ['index.csv', 'track_001.csv']
    # Video time runs from camera 0's first frame, which the scene took at -LEAD_IN.
    assert_matches_truth(read_track(out / 'track_001.csv'), truth, -LEAD_IN)
    with open(out / 'index.csv', newline='') as f:
        header, row = list(csv.reader(f))[:2]
    assert header == ['file', 'wx', 'wy', 'wz', 'label', 'source_id', 'spin_source']
    assert row[header.index('spin_source')] == 'estimated'     # never counted as measured


def test_response_gamma_undoes_a_webcam_response(scene, tmp_path, capsys):
    # The scene's frames as a camera with an sRGB-like response records them (pixel =
    # 255 (light / full)^(1 / 2.2)): told its gamma, tt-perceive sees the light the linear
    # camera saw, and gives its track. It had no option for it: 2-4 times the error, the
    # height high, on another renderer's camera (a new user's walk-through). The exposure
    # and blur are told (the scene's), as estimated they take up part of an untold gamma;
    # the frames are PNG, not compressed: no blur of the values after the response.
    base, rig_path, frames, truth = scene
    lut = np.round(255.0 * (np.arange(256) / 255.0) ** (1.0 / 2.2)).astype(np.uint8)
    rigs = {name: synth.write_scene(str(tmp_path / name), rig_path, scene_frames, [truth],
                                    fmt='png')
            for name, scene_frames in (('linear', frames),
                                       ('webcam', [(t, k, lut[f]) for t, k, f in frames]))}
    tracks = {}
    for name, rig, gamma in (('linear', rigs['linear'], '1'), ('webcam', rigs['webcam'], '2.2'),
                             ('webcam_untold', rigs['webcam'], '1')):
        out = tmp_path / f'out_{name}'
        assert cli.main(['--rig', rig, '--out', str(out), '--response-gamma', gamma,
                         '--exposure', '0.0015', '--image-blur', '0', '--encoded-blur',
                         '0']) == 0
        tracks[name] = read_track(out / 'track_001.csv')
    capsys.readouterr()
    def off(name):          # RMS distance to the linear camera's track, m
        return np.sqrt(np.mean(np.sum((tracks[name][:, 1:4] - tracks['linear'][:, 1:4]) ** 2,
                                      axis=1)))

    assert off('webcam') < 0.25 * off('webcam_untold')
    assert_matches_truth(tracks['webcam'], truth, -LEAD_IN)


@pytest.mark.parametrize('option, setting, value', [
    ([], 'light_from_above', True), (['--any-lighting'], 'light_from_above', False),
    (['--image-blur', '0.6'], 'image_blur', 0.6), (['--image-blur', '0'], 'image_blur', 0.0),
    (['--exposure', '0.003'], 'exposure', 0.003), ([], 'encoded_blur', 0.5),
    (['--encoded-blur', '0'], 'encoded_blur', 0.0)])
def test_the_detector_options_reach_the_detector(scene, tmp_path, monkeypatch, option, setting,
                                                 value):
    # perception_node's light_from_above (the outline fit's choice between a ball lit from
    # above and one lit from below), image_blur (the cameras' own blur in the outline
    # fit: 0.6 px a Bayer camera's demosaicing; synth's clean cameras are sharp) and
    # exposure (the ball's streak; this scene's is 1.5 ms) and encoded_blur (JPEG's blur of
    # the values after a response, 0.5 px by default) are tt-perceive's too; the track
    # is right on this evenly lit scene either way.
    base, rig_path, frames, truth = scene
    made = []
    pipeline = cli.Pipeline

    def recording(*args, **kwargs):
        made.append(kwargs['detector_config'])
        return pipeline(*args, **kwargs)

    monkeypatch.setattr(cli, 'Pipeline', recording)
    rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, [truth], fmt='png')
    out = tmp_path / 'out'
    assert cli.main(['--rig', rig, '--out', str(out), *option]) == 0
    assert made and all(getattr(c, setting) == value for c in made)
    assert_matches_truth(read_track(out / 'track_001.csv'), truth, -LEAD_IN)


def test_each_cameras_blur_is_estimated_by_default_and_tracked_with(scene, tmp_path,
                                                                     monkeypatch, capsys):
    """Without --exposure and --image-blur, tt-perceive estimates each camera's exposure
    and blur from the ball's outline fits (a first pass, at 2 ms and 0.6 px) and tracks with
    them. synth draws the ball over a 1.5 ms exposure at 5 instants spread evenly from its
    start to its end, whose spread along the path (the second moment) is that of a
    continuous streak sqrt((5 + 1) / (5 - 1)) times as long: 1.84 ms, found within 0.25 ms.
    Its clean cameras are sharp (the ball drawn anti-aliased on 1/16 px, no lens, mosaic
    or JPEG), so each camera's blur is found within 0.3 px of 0 (not the 0.6 px a Bayer
    camera has). Each is printed and given to that camera's detector."""
    base, rig_path, frames, truth = scene
    made = []
    pipeline = cli.Pipeline

    def recording(*args, **kwargs):
        made.append(pipeline(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(cli, 'Pipeline', recording)
    rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, [truth], fmt='png')
    out = tmp_path / 'out'
    assert cli.main(['--rig', rig, '--out', str(out)]) == 0
    err = capsys.readouterr().err.splitlines()
    lines = [line for line in err if 'image_blur' in line]
    printed = [float(line.split('image_blur ')[1].split(' px')[0]) for line in lines]
    assert [line.split(':')[1].strip() for line in lines] == ['cam0', 'cam1']
    assert all(0.0 <= b < 0.3 for b in printed), lines
    assert [d.config.image_blur for d in made[-1].detectors] == pytest.approx(printed,
                                                                             abs=0.005)
    lines = [line for line in err if 'exposure' in line]
    printed = [float(line.split('exposure ')[1].split(' ms')[0]) * 1e-3 for line in lines]
    assert [line.split(':')[1].strip() for line in lines] == ['cam0', 'cam1']
    assert printed == pytest.approx([1.5e-3 * np.sqrt(6.0 / 4.0)] * 2, abs=0.25e-3), lines
    assert [d.config.exposure for d in made[-1].detectors] == pytest.approx(printed,
                                                                           abs=5e-6)
    assert_matches_truth(read_track(out / 'track_001.csv'), truth, -LEAD_IN)


def test_the_blur_estimate_keeps_a_bounded_number_of_fits_a_camera(scene, tmp_path,
                                                                    monkeypatch, capsys):
    """A long recording does not pile up outline fits: each camera keeps its latest
    ``BLUR_FITS`` (here 20, of about 70 a camera in this flight), the first pass stops once
    every camera has them, and the estimate rests on that many."""
    base, rig_path, frames, truth = scene
    monkeypatch.setattr(cli, 'BLUR_FITS', 20)
    monkeypatch.setattr(cli, 'BLUR_FITS_MIN', 10)
    rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, [truth], fmt='png')
    out = tmp_path / 'out'
    assert cli.main(['--rig', rig, '--out', str(out)]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if 'outline fits' in line]
    assert len(lines) == 4 and all('from 20 outline fits' in line for line in lines), lines
    assert_matches_truth(read_track(out / 'track_001.csv'), truth, -LEAD_IN)


@pytest.mark.parametrize('value', ['-0.5', '6', 'wide'])
def test_a_camera_blur_out_of_range_is_a_usage_error_naming_it(scene, tmp_path, capsys, value):
    base, rig_path, frames, truth = scene
    out = tmp_path / 'out'
    with pytest.raises(SystemExit) as exit_:
        cli.main(['--rig', rig_path, '--out', str(out), '--image-blur', value])
    assert exit_.value.code == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert '--image-blur' in error and value in error and '[0, 5]' in error
    assert not out.exists()


def test_a_video_overwritten_mid_flight_gives_the_track_and_names_the_frame(scene, tmp_path,
                                                                           capsys):
    # FFmpeg skipped the damaged frame without a word and the frames after it were each timed
    # a frame early: two tracks, the second 7-10 mm off, exit 0 and no warning.
    base, rig_path, frames, truth = scene
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, [truth],
                                  time_offset=0.0)
    cam0 = tmp_path / 'video' / 'cam0.avi'
    overwrite_avi_frame(cam0, 40)                   # the ball in flight
    out = tmp_path / 'out'
    assert cli.main(['--rig', video_rig, '--out', str(out)]) == 0
    n = sum(1 for _, k, _ in frames if k == 0)
    warnings = [line for line in capsys.readouterr().err.splitlines() if 'warning' in line]
    assert warnings == [
        f'tt-perceive: warning: camera cam0: {cam0}: 1 of its {n} frames unreadable '
        '(corrupt?): skipped, the others at their times']     # once, not once a pass
    assert sorted(p.name for p in out.iterdir()) == ['index.csv', 'track_001.csv']
    assert_matches_truth(read_track(out / 'track_001.csv'), truth, -LEAD_IN)


def test_video_files_at_different_rates_are_one_line_and_write_nothing(tmp_path, capsys):
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 150.0)
    frames = [(None, k, np.full((48, 64, 3), 60, np.uint8)) for n in range(3) for k in range(2)]
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, None)
    cam1 = tmp_path / 'video' / 'cam1.avi'
    writer = cv2.VideoWriter(str(cam1), cv2.VideoWriter_fourcc(*'MJPG'), 120.0, (64, 48))
    writer.write(frames[0][2])
    writer.release()
    out = tmp_path / 'out'
    assert cli.main(['--rig', video_rig, '--out', str(out)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and 'cameras cam0 and cam1 run at different rates' in err[0]
    assert f'cam0.avi is 150 fps, {cam1} 120 fps' in err[0]
    assert not out.exists()


@pytest.mark.parametrize('edit', ['transposed', 'none'])
def test_poses_whose_rays_never_meet_are_named_in_a_warning(scene, tmp_path, capsys, edit):
    # A rig with a rotation transposed (a camera-to-table pose) saw the ball in both cameras
    # in every frame and gave '0 track(s)', exit 0, without a word.
    base, rig_path, frames, truth = scene
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, [truth])
    if edit == 'transposed':
        rig = yaml.safe_load(open(video_rig))
        rig['cameras'][1]['rotation'] = np.array(rig['cameras'][1]['rotation']).reshape(
            3, 3).T.ravel().tolist()
        yaml.safe_dump(rig, open(video_rig, 'w'))
    assert cli.main(['--rig', video_rig, '--out', str(tmp_path / 'out')]) == 0
    err = capsys.readouterr().err
    warned = [line for line in err.splitlines() if 'their rays met' in line]
    if edit == 'transposed':
        assert len(warned) == 1 and warned[0].startswith('tt-perceive: warning: two cameras '
                                                         'or more saw a ball at ')
        assert 'x_cam = R x_table + t' in warned[0]
    else:
        assert warned == [], err


def test_ctrl_c_is_one_line_exit_130_and_no_output(scene, tmp_path, capsys, monkeypatch):
    # An interrupt while the frames are processed: no traceback, status 130, no output.
    base, rig_path, frames, truth = scene
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames[:4], [truth])

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(cli, 'run', interrupted)
    out = tmp_path / 'out'
    assert cli.main(['--rig', video_rig, '--out', str(out)]) == 130
    said = capsys.readouterr()
    assert said.err.endswith('tt-perceive: interrupted\n') and 'Traceback' not in said.err
    assert not out.exists()


def test_a_second_run_replaces_the_output_folder(scene, tmp_path, capsys):
    """An earlier run's tracks that this run does not write do not stay behind (a reader
    would take them as tracks of this run); the new folder has the umask's mode."""
    base, rig_path, frames, truth = scene
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, [truth])
    out = tmp_path / 'out'
    out.mkdir(mode=0o700)
    for n in (1, 2, 3):
        (out / f'track_{n:03d}.csv').write_text(','.join(HEADER) + '\n')
    (out / 'index.csv').write_text('file,wx,wy,wz,label,source_id,spin_source\n')
    before = os.umask(0o022)
    try:
        assert cli.main(['--rig', video_rig, '--out', str(out)]) == 0
    finally:
        os.umask(before)
    assert sorted(p.name for p in out.iterdir()) == ['index.csv', 'track_001.csv']
    with open(out / 'index.csv', newline='') as f:
        assert [row[0] for row in list(csv.reader(f))[1:]] == ['track_001.csv']
    assert_matches_truth(read_track(out / 'track_001.csv'), truth, -LEAD_IN)
    assert stat.S_IMODE(out.stat().st_mode) == 0o755
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out', 'video']   # nothing staged


def test_an_out_folder_with_other_files_is_refused_and_left_alone(scene, tmp_path, capsys,
                                                                  monkeypatch):
    """The output replaces the whole folder: a folder holding anything but an earlier output
    (here the rig and its calibration, given as --out by mistake) is refused before any
    work, one line, exit 2."""
    base, rig_path, _, _ = scene
    calib = os.path.dirname(rig_path)
    before = sorted(os.listdir(calib))
    assert cli.main(['--rig', rig_path, '--out', calib]) == 2
    said = capsys.readouterr()
    err = said.err.strip().splitlines()
    assert said.out == '' and len(err) == 1 and f'--out {calib}' in err[0]
    assert sorted(os.listdir(calib)) == before
    # The same folder as the current one, by another name: an empty --out (an unset shell
    # variable) or 'missing/..' (the tracks replaced the folder the command ran in).
    monkeypatch.chdir(calib)
    for out in ('', 'missing/..'):
        assert cli.main(['--rig', rig_path, '--out', out]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f'--out {out}' in err[0]
    assert sorted(os.listdir(calib)) == before


@pytest.mark.parametrize('lag', [0.0123, 0.005])
def test_time_offset_of_unsynchronised_videos_is_estimated(tmp_path, capsys, lag):
    """Camera 1 exposes ``lag`` after camera 0 (0.0123 s: 1.85 frames). At 0.005 s the
    swinging disc beside the ball left too few frames with a single detection in camera 1,
    and the offset came out 27 ms off (no track; a new user's walk-through, 29 Nov 2026):
    every detection now counts, linked into image tracks."""
    rig_path = synth.make_rig(str(tmp_path / 'calib'))
    frames, truth = synth.render_balls(load_rig(rig_path), [synth.incoming_ball(speed=9.0)],
                                       [0.0], duration=0.5, lead_in=LEAD_IN,
                                       time_offsets=[0.0, lag])
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, truth)
    out = tmp_path / 'out'
    assert cli.main(['--rig', video_rig, '--out', str(out)]) == 0
    note = [line for line in capsys.readouterr().err.splitlines() if 'time_offset' in line]
    # Each file's clock starts at its first frame: camera 1's runs `lag` behind camera 0's.
    estimated = float(note[0].split('time_offset ')[1].split(' ms')[0]) * 1e-3
    assert abs(estimated - -lag) < 5e-4
    assert_matches_truth(read_track(out / 'track_001.csv'), truth[0], -LEAD_IN)


def test_an_offset_estimated_from_the_blobs_is_refined_from_the_outline_fits(tmp_path, capsys):
    """Synchronised cameras (true offset 0), the rig without time_offset, an orange ball
    under the hall's light: the blobs' centres lean toward the lit side, each camera's its
    own way, and the offset they gave was -1.0 ms, the states 5.7 mm RMS off (a new user's
    walk-through, 5 Dec 2026). Refined from the centres fitted to the outline, it is within
    a third of a millisecond and the track within 2 mm RMS, as with time_offset 0."""
    rig_path = synth.make_rig(str(tmp_path / 'calib'))
    ball = synth.incoming_ball(speed=8.0, topspin_rps=40.0, sidespin_rps=10.0)
    frames, truth = synth.render_balls(load_rig(rig_path), [ball], [0.0], colour='orange',
                                       duration=1.0, lead_in=LEAD_IN, exposure=2e-3,
                                       imaging='hall')
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, truth)
    out = tmp_path / 'out'
    assert cli.main(['--rig', video_rig, '--out', str(out), '--colour', 'orange']) == 0
    refined = [line for line in capsys.readouterr().err.splitlines() if 'refined to' in line]
    assert len(refined) == 1 and refined[0].startswith('tt-perceive: cam1: '), refined
    offset = float(refined[0].split('refined to ')[1].split(' ms')[0]) * 1e-3
    assert abs(offset) < 3e-4
    assert_matches_truth(read_track(out / 'track_001.csv'), truth[0], -LEAD_IN)


def test_camera_0s_own_time_offset_is_in_the_estimated_ones(tmp_path, capsys):
    """Camera 0's time_offset is a delay of its own stamps (a V4L2 driver's readout): its
    frames are taken back by it, so camera 1's estimate, made between the files' clocks,
    must include it (a new user's walk-through: 10 ms on camera 0 alone split the flight
    into two tracks of 39 states, exit 0). The track's times are camera 0's less it."""
    rig_path = synth.make_rig(str(tmp_path / 'calib'))
    lag, delay = 0.0123, 0.01
    frames, truth = synth.render_balls(load_rig(rig_path), [synth.incoming_ball(speed=9.0)],
                                       [0.0], duration=0.5, lead_in=LEAD_IN,
                                       time_offsets=[0.0, lag])
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, truth)
    rig = yaml.safe_load(pathlib.Path(video_rig).read_text())
    rig['cameras'][0]['time_offset'] = delay
    pathlib.Path(video_rig).write_text(yaml.safe_dump(rig))
    out = tmp_path / 'out'
    assert cli.main(['--rig', video_rig, '--out', str(out)]) == 0
    note = [line for line in capsys.readouterr().err.splitlines() if 'time_offset' in line]
    assert len(note) == 1 and "(camera 0's +10.000 ms included)" in note[0], note
    estimated = float(note[0].split('time_offset ')[1].split(' ms')[0]) * 1e-3
    assert abs(estimated - (delay - lag)) < 5e-4
    assert sorted(p.name for p in out.iterdir()) == ['index.csv', 'track_001.csv']
    assert_matches_truth(read_track(out / 'track_001.csv'), truth[0], delay - LEAD_IN)


def test_a_camera_that_never_sees_the_ball_gets_a_warning_not_a_crash(scene, tmp_path, capsys):
    """Camera 1's video shows only the empty table (a camera pointed elsewhere, a lens cap):
    its time offset cannot be estimated, which is one warning line, exit 0 and no track (an
    IndexError with a traceback before: a new user's walk-through, 29 Nov 2026)."""
    base, rig_path, frames, truth = scene
    empty = next(frame for t, k, frame in frames if k == 1)       # before the launch
    blind = [(t, k, empty if k == 1 else frame) for t, k, frame in frames]
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, blind, None)
    out = tmp_path / 'out'
    assert cli.main(['--rig', video_rig, '--out', str(out)]) == 0
    err = capsys.readouterr().err
    assert 'Traceback' not in err
    assert any(line.startswith('tt-perceive: warning: cam1: too few ball detections')
               for line in err.splitlines()), err
    assert sorted(p.name for p in out.iterdir()) == ['index.csv']


def test_time_offset_without_a_colour_is_estimated_from_the_ball_and_not_the_rest(tmp_path,
                                                                                   capsys):
    """An orange ball under the hall's light, the swinging racket and sleeve in view, and
    no --colour: the frames with a single detection of any colour are mostly not the ball
    (it comes with the racket's and the shadows'), and the offset they gave was 22 ms off,
    with no track. The white and the orange ball's detections are tried instead, and the
    orange ball's put their pairs on the epipolar lines."""
    rig_path = synth.make_rig(str(tmp_path / 'calib'))
    lag = 0.0123
    frames, truth = synth.render_balls(load_rig(rig_path), [synth.incoming_ball(speed=9.0)],
                                       [0.0], colour='orange', duration=0.5, lead_in=LEAD_IN,
                                       time_offsets=[0.0, lag], imaging='hall',
                                       exposure=2e-3)
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, truth)
    out = tmp_path / 'out'
    assert cli.main(['--rig', video_rig, '--out', str(out)]) == 0
    err = capsys.readouterr().err.splitlines()
    note = [line for line in err if 'time_offset' in line]
    assert len(note) == 1 and '(as the orange detector finds it)' in note[0]
    estimated = float(note[0].split('time_offset ')[1].split(' ms')[0]) * 1e-3
    # Within the half frame the outline fits refine it in, and refined to within 0.3 ms.
    assert abs(estimated - -lag) < 0.5 / 150.0
    refined = [line for line in err if 'its time offset refined to' in line]
    assert len(refined) == 1
    estimated = float(refined[0].split('refined to ')[1].split(' ms')[0]) * 1e-3
    assert abs(estimated - -lag) < 3e-4
    # The track is there and on the ball (an orange ball at 640x480 under JPEG's halved
    # chroma is a few millimetres off at the far end: docs/perception.md, so the median).
    rows = read_track(out / 'track_001.csv')
    t = rows[:, 0] - LEAD_IN
    idx = np.array([int(np.argmin(np.abs(truth[0]['t'] - ti))) for ti in t])
    err = np.linalg.norm(rows[:, 1:4] - truth[0]['state'][idx, :3], axis=1)
    assert len(rows) > 40 and np.median(err) < 2e-3


def _image_bag(bag, frames, t0, only=(0, 1), compressed=None, stamped=True):
    """A bag of the frames as sensor_msgs/Image on /cam0/image_raw and /cam1/image_raw, stamped
    t0 + t; the frames of the cameras not in ``only`` are left out (their topic declared).
    ``compressed`` ('png' or 'jpeg'): as sensor_msgs/CompressedImage on
    /camN/image_raw/compressed instead, as image_transport's compressed transport records.
    Not ``stamped``: the header stamps left 0 (the bag's record times still t0 + t)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    Header = store.types['std_msgs/msg/Header']
    Time = store.types['builtin_interfaces/msg/Time']
    msgtype = 'sensor_msgs/msg/CompressedImage' if compressed else 'sensor_msgs/msg/Image'
    suffix = '/compressed' if compressed else ''
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = [writer.add_connection(f'/cam{k}/image_raw{suffix}', msgtype, typestore=store)
                 for k in range(2)]
        for t, k, frame in frames:
            if k not in only:
                continue
            ns = int(round((t0 + t) * 1e9))
            stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9) if stamped else Time(sec=0,
                                                                                    nanosec=0)
            header = Header(stamp=stamp, frame_id=f'cam{k}')
            if compressed:
                ok, data = cv2.imencode('.png' if compressed == 'png' else '.jpg', frame)
                msg = store.types[msgtype](header=header,
                                           format=f'bgr8; {compressed} compressed bgr8',
                                           data=data.reshape(-1))
            else:
                msg = store.types[msgtype](header=header, height=frame.shape[0],
                                           width=frame.shape[1], encoding='bgr8',
                                           is_bigendian=0, step=frame.shape[1] * 3,
                                           data=frame.reshape(-1))
            writer.write(conns[k], ns, store.serialize_cdr(msg, msgtype))


def test_images_without_header_stamps_are_timed_by_the_bag_and_named(scene, tmp_path,
                                                                       capsys):
    # A camera driver that leaves header.stamp at 0: every frame was at t = 0 (no track).
    base, rig_path, frames, truth = scene
    bag = tmp_path / 'bag'
    _image_bag(bag, frames, 500.0, stamped=False)
    out = tmp_path / 'out'
    assert cli.main(['--rig', rig_path, '--out', str(out), '--bag', str(bag)]) == 0
    assert_matches_truth(read_track(out / 'track_001.csv'), truth, -500.0)
    err = capsys.readouterr().err
    for k in range(2):
        assert (f'warning: {bag}: camera cam{k} (/cam{k}/image_raw): images without a header '
                'stamp, timed by when the bag recorded them') in err


def test_a_bag_of_cameras_slower_than_the_rigs_fps_is_named(scene, tmp_path, capsys):
    # Cameras at 30 fps in a rig of 150: tracking, which times the frames by the rig's fps,
    # gave no state and no word (a lab's walk-through); the stamps show the rate.
    base, rig_path, frames, truth = scene
    few = [f for f in frames if f[0] < 0.3]
    slow = [f for f in few if round(f[0] * 150) % 5 == 0]
    for name, kept in (('full', few), ('slow', slow)):
        _image_bag(tmp_path / name, kept, 500.0)
        cli.main(['--rig', rig_path, '--out', str(tmp_path / f'out_{name}'), '--bag',
                  str(tmp_path / name)])
        err = capsys.readouterr().err
        named = [f'camera cam{k}: its frames come at 30 fps (their stamps), the rig' in err
                 for k in range(2)]
        assert named == ([True, True] if name == 'slow' else [False, False]), err

def test_bag_of_compressed_images_gives_the_states_of_the_images(scene, tmp_path):
    # image_transport's compressed topics, as a ROS user records cameras: PNG is lossless,
    # so the states are those of the raw images; the rig names the compressed topics.
    base, rig_path, frames, truth = scene
    few = [f for f in frames if f[0] < 0.25]
    raw_bag, png_bag = tmp_path / 'raw', tmp_path / 'png'
    _image_bag(raw_bag, few, 500.0)
    _image_bag(png_bag, few, 500.0, compressed='png')
    compressed_rig = tmp_path / 'rig.yaml'
    compressed_rig.write_text(pathlib.Path(rig_path).read_text().replace(
        '/image_raw', '/image_raw/compressed'))
    for name in ('cam0.yaml', 'cam1.yaml'):
        (tmp_path / name).write_text((pathlib.Path(rig_path).parent / name).read_text())
    assert cli.main(['--rig', rig_path, '--out', str(tmp_path / 'out_raw'), '--bag',
                     str(raw_bag)]) == 0
    assert cli.main(['--rig', str(compressed_rig), '--out', str(tmp_path / 'out_png'),
                     '--bag', str(png_bag)]) == 0
    raw = read_track(tmp_path / 'out_raw' / 'track_001.csv')
    assert len(raw) > 15
    assert np.array_equal(read_track(tmp_path / 'out_png' / 'track_001.csv'), raw)


def test_bag_of_images_gives_one_track(scene, tmp_path):
    base, rig_path, frames, truth = scene
    bag = tmp_path / 'bag'
    t0 = 500.0
    _image_bag(bag, frames, t0)
    out = tmp_path / 'out'
    states = tmp_path / 'states'
    assert cli.main(['--rig', rig_path, '--out', str(out), '--bag', str(bag),
                     '--out-bag', str(states)]) == 0
    rows = read_track(out / 'track_001.csv')
    assert_matches_truth(rows, truth, -t0)   # the bag's stamps
    # The same states as BallState in the output bag, stamped with the images' stamps.
    from rosbags.highlevel import AnyReader
    from tt_ros.bagfile import TypeRegistry
    registry = TypeRegistry()
    registry.ensure('tt_msgs/msg/BallState')
    with AnyReader([states], default_typestore=registry.store) as reader:
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert len(msgs) == len(rows)
    for msg, row in zip(msgs, rows, strict=True):
        assert abs(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec - row[0]) < 1e-6
        assert np.allclose([msg.position.x, msg.spin.z], [row[1], row[9]], atol=1e-6)
        assert msg.track_id == 1 and msg.covariance.shape == (81,)
    # A rig whose camera 1 reads a topic the bag lacks: no point can be made (it gave 0
    # tracks and exit 0 without a word).
    moved = tmp_path / 'moved.yaml'
    moved.write_text(pathlib.Path(rig_path).read_text().replace('/cam1/image_raw',
                                                                '/cam9/image_raw'))
    for name in ('cam0.yaml', 'cam1.yaml'):
        (tmp_path / name).write_text((pathlib.Path(rig_path).parent / name).read_text())
    assert cli.main(['--rig', str(moved), '--out', str(tmp_path / 'out2'), '--bag',
                     str(bag)]) == 1
    assert not (tmp_path / 'out2').exists()


def test_a_bag_without_images_or_of_another_size_for_a_camera_is_refused(scene, tmp_path,
                                                                        capsys):
    """A new user's walk-through: camera 1's topic declared in the bag with no image, or its
    images half the calibration's size, gave 0 tracks and exit 0 (the second with a
    warning); a video file of another size is refused. Now one line naming the camera,
    exit 1, nothing written."""
    base, rig_path, frames, _ = scene
    few = frames[:12]
    small = [(t, k, cv2.resize(f, (f.shape[1] // 2, f.shape[0] // 2)) if k == 1 else f)
             for t, k, f in few]
    for name, bag_frames, only, expect in (
            ('declared', few, (0,), 'no sensor_msgs/Image or CompressedImage for camera(s) cam1 '
             '(/cam1/image_raw)'),
            ('small', small, (0, 1), 'camera cam1 (/cam1/image_raw): images 320x240, its '
                                     'calibration 640x480')):
        bag = tmp_path / f'bag_{name}'
        _image_bag(bag, bag_frames, 500.0, only)
        out = tmp_path / f'out_{name}'
        assert cli.main(['--rig', rig_path, '--out', str(out), '--bag', str(bag)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and expect in err[0], err
        assert not out.exists()


@pytest.mark.parametrize('args, code, expect', [
    (['--rig', '{tmp}/absent.yaml'], 2, 'absent.yaml: no such file'),
    (['--rig', '{tmp}'], 2, ': not a file'),
    (['--rig', '{tmp}/empty.yaml'], 2, 'empty.yaml: empty'),
    (['--rig', '{rig}'], 1,
     "source '/cam0/image_raw' is not a video file (an image topic: read from a bag, --bag)"),
    (['--rig', '{rig}', '--bag', '{tmp}/nobag'], 1, 'not a readable rosbag2 bag'),
    (['--rig', '{rig}', '--bag', '{tmp}/badbag'], 1,
     '{tmp}/badbag: not a readable rosbag2 bag: Could not load YAML'),
    # 'Expected metadata file ... does not exist' (rosbags'; ros2 bag info says killed?).
    (['--rig', '{rig}', '--bag', '{tmp}/killed'], 1,
     '{tmp}/killed: not a readable rosbag2 bag: incomplete: killed_0.mcap without '
     'metadata.yaml (a recording that did not end: killed?)'),
    # "Expected metadata file '<the folder>' does not exist" (a walk-through, 7 Dec 2026).
    (['--rig', '{rig}', '--bag', '{tmp}/emptydir'], 1,
     '{tmp}/emptydir: not a readable rosbag2 bag: no metadata.yaml in it'),
    (['--rig', '{rig}', '--model', '{tmp}/absent_model.yaml'], 2, 'absent_model.yaml'),
    (['--rig', '{rig}', '--out-bag', '{tmp}'], 2, '--out-bag {tmp}: already exists'),
    (['--rig', '{rig}', '--out-bag', '{tmp}/dangling'], 2,
     '--out-bag {tmp}/dangling: already exists'),
    (['--rig', '{rig}', '--out-bag', '{tmp}/empty.yaml/states'], 2,
     '--out-bag {tmp}/empty.yaml/states: cannot write: Not a directory'),
    (['--rig', '{rig}', '--out-bag', '{tmp}/out/states'], 2, 'inside --out'),
    (['--rig', '{dup}'], 2, 'cameras cam0 and cam1 are 0.000 m apart'),
    (['--rig', '{nosrc}'], 2, 'cameras[1] (cam1): no source'),
], ids=['missing rig', 'rig is a folder', 'empty rig', 'topics without a bag', 'missing bag',
        'bag metadata not YAML',
        'killed bag', 'empty folder as bag', 'missing model', 'existing output bag',
        'dangling link as output bag',
        'output bag under a file', 'output bag inside --out', 'two cameras at one place',
        'camera without a source'])
def test_bad_input_is_one_line_and_writes_nothing(scene, tmp_path, capsys, args, code, expect):
    """Checked before any work (the rig's topics without --bag would fail later, exit 1)."""
    base, rig_path, _, _ = scene
    out = tmp_path / 'out'
    (tmp_path / 'empty.yaml').write_text('')
    (tmp_path / 'dangling').symlink_to(tmp_path / 'nowhere')
    (tmp_path / 'killed').mkdir()
    (tmp_path / 'emptydir').mkdir()
    (tmp_path / 'killed' / 'killed_0.mcap').write_bytes(b'\x89MCAP0\r\n')
    (tmp_path / 'badbag').mkdir()          # the YAML parser's error spans five lines
    (tmp_path / 'badbag' / 'metadata.yaml').write_text('rosbag2_bagfile_information: [9\n')
    dup = tmp_path / 'calib'
    synth.make_rig(str(dup))
    rig = yaml.safe_load((dup / 'rig.yaml').read_text())
    for key in ('rotation', 'translation'):          # a camera block copied, renamed
        rig['cameras'][1][key] = rig['cameras'][0][key]
    (dup / 'rig.yaml').write_text(yaml.safe_dump(rig))
    # No source: the rig's own folder (its calibration images) was read as a video.
    rig = yaml.safe_load(pathlib.Path(rig_path).read_text())
    del rig['cameras'][1]['source']
    nosrc = pathlib.Path(rig_path).parent / 'nosrc.yaml'
    nosrc.write_text(yaml.safe_dump(rig))
    expect = expect.format(tmp=tmp_path)
    args = [a.format(tmp=tmp_path, rig=rig_path, dup=dup / 'rig.yaml', nosrc=nosrc)
            for a in args]
    args += ['--out', str(out)]
    assert cli.main(args) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expect in err[0]
    named = [a for a in args if str(tmp_path) in a and a != str(out)]
    assert all(err[0].count(f'{a}:') == 1 for a in named)    # each path named once
    assert not out.exists()


def test_a_bag_that_fails_at_the_end_leaves_nothing(scene, tmp_path, capsys, monkeypatch):
    """A bag that cannot be written after the run (a full disk): one line naming --out-bag,
    exit 1, and neither the bag nor the track folder (staged: moved in together) nor any
    staging folder is left."""
    base, rig_path, frames, truth = scene
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames[:40], [truth])

    def full(path, estimates, frame_id):
        os.mkdir(path)
        (pathlib.Path(path) / 'states_0.mcap').write_bytes(b'partial')
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(cli, 'write_bag', full)
    out, bag = tmp_path / 'out', tmp_path / 'states'
    assert cli.main(['--rig', video_rig, '--out', str(out), '--out-bag', str(bag)]) == 1
    said = capsys.readouterr()
    err = said.err.splitlines()            # the notes of the run, then the error
    assert err[-1] == f'tt-perceive: --out-bag {bag}: cannot write: No space left on device'
    assert sum('--out-bag' in line for line in err) == 1
    assert 'Traceback' not in said.err and said.out == ''
    assert sorted(p.name for p in tmp_path.iterdir()) == ['video']


def velocity_errors(rows, truth, t_shift):
    """|v - v_true| of each row from 50 ms after the first, the 50 ms after the bounce left out
    (the rebound's spin along v is unknown until its samples come: docs/perception.md)."""
    t = rows[:, 0] + t_shift
    idx = np.array([int(np.argmin(np.abs(truth['t'] - ti))) for ti in t])
    bounce = [e.t for e in truth['events'] if e.kind == 'bounce'][0]
    judged = (t >= t[0] + 0.05) & ~((t >= bounce) & (t < bounce + 0.05))
    return np.linalg.norm(rows[:, 4:7] - truth['state'][idx, 3:6], axis=1)[judged]


def test_smooth_gives_each_state_all_of_its_tracks_frames(scene, tmp_path, capsys):
    """By default the states are the filter's, as the live node publishes them; with --smooth
    each is given all of its track's frames (fixed-interval smoother). Same rows and times;
    the smoothed velocity, which the frames after each state pin too, is within the issue's
    0.05 m/s and at most half the filter's largest error."""
    base, rig_path, frames, truth = scene
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, [truth])
    tracks = {}
    for name, extra in (('smoothed', ['--smooth']), ('filtered', [])):
        out = tmp_path / name
        assert cli.main(['--rig', video_rig, '--out', str(out)] + extra) == 0
        tracks[name] = read_track(out / 'track_001.csv')
        assert_matches_truth(tracks[name], truth, -LEAD_IN)
    assert np.array_equal(tracks['smoothed'][:, 0], tracks['filtered'][:, 0])
    smoothed = velocity_errors(tracks['smoothed'], truth, -LEAD_IN)
    filtered = velocity_errors(tracks['filtered'], truth, -LEAD_IN)
    assert smoothed.max() <= min(0.05, 0.5 * filtered.max())
