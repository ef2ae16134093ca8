"""Frame sources: classification of rig sources, image messages to BGR, files, and a V4L2
device that is absent or vanishes (reported and retried, never raised from read)."""

import cv2
import numpy as np
import pytest
from tt_perception.camera import load_rig
from tt_perception.sources import (
    V4L2Source,
    VideoFileSource,
    file_frames,
    image_to_bgr,
    source_kind,
)

from tt_perception import synth


@pytest.mark.parametrize('source, kind', [
    ('/dev/video0', 'v4l2'), ('2', 'v4l2'), ('cam0.avi', 'file'), ('cam0/%06d.png', 'file'),
    ('cam0_frames/', 'file'),
    ('/cam0/image_raw', 'topic'), ('left/image_rect', 'topic')])
def test_source_kind(source, kind):
    assert source_kind(source) == kind


def test_a_folder_of_images_is_looked_for_beside_the_rig(tmp_path, monkeypatch):
    # 'cam0_frames' (no trailing slash) beside the rig was a topic when the rig was used from
    # another directory: tt-perceive refused it, perception_node waited for images for ever.
    (tmp_path / 'rig' / 'cam0_frames').mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    assert source_kind('cam0_frames') == 'topic'
    assert source_kind('cam0_frames', str(tmp_path / 'rig')) == 'file'


def test_image_encodings_become_the_same_bgr():
    rng = np.random.default_rng(1)
    bgr = rng.integers(0, 255, (4, 5, 3), dtype=np.uint8)
    rgb = bgr[:, :, ::-1]
    padded = np.zeros((4, 16), np.uint8)          # step larger than width * channels
    padded[:, :15] = bgr.reshape(4, 15)
    assert np.array_equal(image_to_bgr('bgr8', 4, 5, 15, bgr.tobytes()), bgr)
    assert np.array_equal(image_to_bgr('rgb8', 4, 5, 15, rgb.tobytes()), bgr)
    assert np.array_equal(image_to_bgr('bgr8', 4, 5, 16, padded.tobytes()), bgr)
    grey = image_to_bgr('mono8', 4, 5, 5, bgr[:, :, 0].tobytes())
    assert np.array_equal(grey[:, :, 2], bgr[:, :, 0])
    with pytest.raises(ValueError, match='encoding .yuv422. not supported'):
        image_to_bgr('yuv422', 4, 5, 10, bytes(40))
    with pytest.raises(ValueError, match='does not hold 5x4 bgr8'):
        image_to_bgr('bgr8', 4, 5, 15, bytes(10))


def test_image_sequence_is_read_in_order_with_frame_times(tmp_path):
    for i in range(3):
        cv2.imwrite(str(tmp_path / f'{i:04d}.png'), np.full((6, 8, 3), 40 * i, np.uint8))
    src = VideoFileSource(str(tmp_path), 100.0).open()
    got = [src.read() for _ in range(4)]
    assert [t for t, _ in got[:3]] == [0.0, 0.01, 0.02]
    assert [int(f[0, 0, 0]) for _, f in got[:3]] == [0, 40, 80]
    assert got[3] == (None, None)
    with pytest.raises(OSError, match='no such video file'):
        VideoFileSource(str(tmp_path / 'absent.avi'), 100.0).open()


def test_a_pattern_matching_no_image_is_one_line_without_ffmpeg_log(tmp_path, capfd):
    # FFmpeg's image2 demuxer logs '[image2 @ 0x...] Could find no file ...' on the process's
    # stderr before OpenCV says the capture is not open; the user is told once, by the error.
    pattern = str(tmp_path / 'frame%04d.png')
    with pytest.raises(OSError, match='no image matches the pattern'):
        VideoFileSource(pattern, 100.0).open()
    assert '[image2' not in capfd.readouterr().err
    cv2.imwrite(str(tmp_path / 'frame0003.png'), np.zeros((6, 8, 3), np.uint8))
    assert VideoFileSource(pattern, 100.0).open().read()[1].shape == (6, 8, 3)


def test_scene_videos_are_read_back_camera_by_camera(tmp_path):
    # write_scene's videos (synth.CameraVideos, MJPG) through file_frames: each camera's
    # frames in turn at each index, at index / fps; no truth given, no truth.csv.
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 100.0)
    frames = [(None, k, np.full((48, 64, 3), 40 * n + 20 * k, np.uint8))
              for n in range(3) for k in range(2)]
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, None)
    assert not (tmp_path / 'video' / 'truth.csv').exists()
    rig = load_rig(video_rig)
    assert [cam.source for cam in rig.cameras] == ['cam0.avi', 'cam1.avi']
    got = [(t, k, int(round(frame.mean()))) for t, k, frame in file_frames(rig)]
    assert [(t, k) for t, k, _ in got] == [(0.0, 0), (0.0, 1), (0.01, 0), (0.01, 1),
                                           (0.02, 0), (0.02, 1)]
    assert all(abs(grey - (40 * (i // 2) + 20 * k)) <= 2 for i, (_, k, grey) in enumerate(got))


def test_a_video_cut_short_is_named_with_the_frames_it_lacks(tmp_path):
    # 20 MJPG frames per camera; cam0's file then cut: its header still declares 20.
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 100.0)
    rng = np.random.default_rng(0)
    frames = [(None, k, rng.integers(0, 255, (48, 64, 3), np.uint8))
              for n in range(20) for k in range(2)]
    rig = load_rig(synth.write_scene(str(tmp_path / 'video'), rig_path, frames, None))
    whole = []
    assert len(list(file_frames(rig, whole))) == 40 and whole == []
    cam0 = tmp_path / 'video' / 'cam0.avi'
    cam0.write_bytes(cam0.read_bytes()[:cam0.stat().st_size // 2])
    notes = []
    read = sum(k == 0 for _, k, _ in file_frames(rig, notes))
    assert 0 < read < 19
    assert notes == [f'camera cam0: {cam0}: video ended after {read} of the 20 frames its '
                     'header declares (cut or corrupt?)']


def test_a_video_of_another_size_or_rate_than_its_rig_is_named(tmp_path):
    # 64x48 videos at 100 fps; a rig whose cam1 calibration is 128x96 (another camera's
    # camera_info), then one whose fps is 150 (another camera setting).
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 100.0)
    frames = [(None, k, np.full((48, 64, 3), 60, np.uint8)) for n in range(3) for k in range(2)]
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, None)
    rig = load_rig(video_rig)
    rig.cameras[1].width, rig.cameras[1].height = 128, 96
    with pytest.raises(OSError) as refused:
        list(file_frames(rig))
    assert str(refused.value) == (f"camera cam1: {tmp_path / 'video' / 'cam1.avi'} is 64x48, "
                                  'its calibration (camera_info) 128x96')
    rig = load_rig(video_rig)
    rig.fps = 150.0
    notes = []
    assert len(list(file_frames(rig, notes))) == 6
    assert notes == [f"camera cam{k}: {tmp_path / 'video' / f'cam{k}.avi'} is 100 fps, the "
                     "rig's fps 150: its frames are timed at the rig's" for k in (0, 1)]


def test_absent_v4l2_device_is_reported_and_retried(capfd):
    src = V4L2Source('/dev/video_tt_absent', reopen_interval=0.0)
    with pytest.raises(OSError, match='/dev/video_tt_absent: no such V4L2 device'):
        src.open()
    # read() never raises: it tries to reopen and says why nothing came.
    assert src.read() == (None, None)
    assert 'no such V4L2 device' in src.status
    # Only the node's line: OpenCV's own warning came at every try, twice a second.
    assert 'WARN' not in capfd.readouterr().err
