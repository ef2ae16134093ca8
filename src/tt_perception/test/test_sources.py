"""Frame sources: classification of rig sources, image messages to BGR, files, and a V4L2
device that is absent or vanishes (reported and retried, never raised from read)."""

import errno
import os

import cv2
import numpy as np
import pytest
from tt_perception.camera import load_rig
from tt_perception.sources import (
    V4L2Source,
    VideoFileSource,
    camera_info_topic,
    compressed_to_bgr,
    file_frames,
    file_sources_error,
    image_to_bgr,
    source_kind,
)

from tt_perception import sources, synth


@pytest.mark.parametrize('source, kind', [
    ('/dev/video0', 'v4l2'), ('2', 'v4l2'), ('cam0.avi', 'file'), ('cam0/%06d.png', 'file'),
    ('cam0_frames/', 'file'), ('cam0.m4v', 'file'), ('cam0.mts', 'file'),
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
    with pytest.raises(ValueError, match='encoding .16UC1. not supported'):
        image_to_bgr('16UC1', 4, 5, 10, bytes(40))
    with pytest.raises(ValueError, match='does not hold 5x4 bgr8'):
        image_to_bgr('bgr8', 4, 5, 15, bytes(10))
    with pytest.raises(ValueError, match='yuv422 needs an even width'):
        image_to_bgr('yuv422', 4, 5, 10, bytes(40))


# The colour of each site of a 2 x 2 Bayer tile, by the pattern's name read row by row.
BAYER_SITES = {'bayer_rggb8': 'RGGB', 'bayer_bggr8': 'BGGR', 'bayer_gbrg8': 'GBRG',
               'bayer_grbg8': 'GRBG'}


@pytest.mark.parametrize('encoding', sorted(BAYER_SITES))
def test_a_bayer_camera_image_is_demosaiced_to_its_colours(encoding):
    # A flat scene of one colour (B, G, R) = (40, 120, 220), sampled as the pattern says:
    # each pixel keeps the channel of its site. Demosaiced, the inside is that colour.
    colour = {'B': 40, 'G': 120, 'R': 220}
    sites = BAYER_SITES[encoding]
    mosaic = np.zeros((8, 10), np.uint8)
    for i, site in enumerate(sites):
        mosaic[i // 2::2, i % 2::2] = colour[site]
    bgr = image_to_bgr(encoding, 8, 10, 10, mosaic.tobytes())
    assert bgr.shape == (8, 10, 3)
    inside = bgr[2:-2, 2:-2].reshape(-1, 3).astype(int)
    assert np.all(np.abs(inside - [colour['B'], colour['G'], colour['R']]) <= 1)


@pytest.mark.parametrize('encoding, order', [('yuv422', 'UYVY'), ('yuv422_yuy2', 'YUYV')])
def test_a_yuv422_image_gives_the_bt601_colours(encoding, order):
    # BT.601 limited range (as USB cameras send): R = 1.164 (Y - 16) + 1.596 (V - 128),
    # G = 1.164 (Y - 16) - 0.813 (V - 128) - 0.391 (U - 128), B = 1.164 (Y - 16) + 2.018
    # (U - 128).
    y, u, v = 100, 110, 170
    values = {'Y': y, 'U': u, 'V': v}
    row = np.array([values[c] for c in order] * 4, np.uint8)     # 8 pixels
    data = np.tile(row, (2, 1))
    bgr = image_to_bgr(encoding, 2, 8, 16, data.tobytes()).reshape(-1, 3).astype(float)
    expected = [1.164 * (y - 16) + 2.018 * (u - 128),
                1.164 * (y - 16) - 0.813 * (v - 128) - 0.391 * (u - 128),
                1.164 * (y - 16) + 1.596 * (v - 128)]
    assert np.all(np.abs(bgr - expected) <= 2.0)


@pytest.mark.parametrize('image_format, extension', [
    ('bgr8; png compressed bgr8', '.png'), ('rgb8; jpeg compressed bgr8', '.jpg'),
    ('jpeg', '.jpg'), ('mono8; png compressed mono8', '.png')])
def test_a_compressed_image_decodes_to_its_pixels(image_format, extension):
    rng = np.random.default_rng(2)
    # Flat 16 x 16 tiles (a JPEG colour block each): what JPEG keeps nearly as it is.
    bgr = np.repeat(np.repeat(rng.integers(0, 255, (2, 3, 3), np.uint8), 16, 0), 16, 1)
    if image_format.startswith('mono8'):
        bgr = np.repeat(bgr[:, :, :1], 3, axis=2)
    ok, data = cv2.imencode(extension, bgr[:, :, 0] if image_format.startswith('mono8')
                            else bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    out = compressed_to_bgr(image_format, data.tobytes())
    assert out.shape == bgr.shape and out.dtype == np.uint8
    if extension == '.png':                      # lossless
        assert np.array_equal(out, bgr)
    else:                                        # each tile's middle (JPEG's 4:2:0 chroma
        middle = np.s_[8::16, 8::16]             # smears colour across the tiles' edges)
        assert np.abs(out[middle].astype(int) - bgr[middle]).max() <= 4


def test_a_compressed_image_that_is_not_one_is_refused():
    with pytest.raises(ValueError, match='does not decode as JPEG or PNG'):
        compressed_to_bgr('jpeg', b'not a jpeg')
    with pytest.raises(ValueError, match='does not decode'):
        compressed_to_bgr('jpeg', b'')
    ok, data = cv2.imencode('.png', np.zeros((4, 4), np.uint16))
    with pytest.raises(ValueError, match='compressedDepth.*not supported'):
        compressed_to_bgr('16UC1; compressedDepth png', data.tobytes())


@pytest.mark.parametrize('topic, info', [
    ('/cam0/image_raw', '/cam0/camera_info'), ('image_raw', 'camera_info'),
    ('/cam0/image_raw/compressed', '/cam0/camera_info'),
    ('/left/image_rect/compressed/', '/left/camera_info')])
def test_camera_info_is_looked_for_beside_the_image_topic(topic, info):
    assert camera_info_topic(topic) == info


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


def test_a_folder_of_images_numbered_from_100_with_a_gap_keeps_each_frames_time(tmp_path,
                                                                                   capfd):
    """Images 100..105 without 102 (a frame the grabber lost) at 100 fps: frame n is image
    100 + n at n / 100 s, the missing one is a lost frame named at the end, and the images
    after it keep their times. FFmpeg's image2 reader, which the folder went to before,
    wanted a first number within 0-4 (exit 2) and stopped at the first gap (129 of 180
    frames thrown away: a new user's walk-through, 29 Nov 2026)."""
    for i in (100, 101, 103, 104, 105):
        cv2.imwrite(str(tmp_path / f'img_{i:06d}.png'), np.full((6, 8), i, np.uint8))
    src = VideoFileSource(str(tmp_path), 100.0).open()
    got = [src.read() for _ in range(7)]
    assert [t for t, _ in got[:6]] == pytest.approx([0.0, 0.01, 0.02, 0.03, 0.04, 0.05])
    assert [None if f is None else int(f[0, 0, 0]) for _, f in got[:6]] == [
        100, 101, None, 103, 104, 105]
    assert got[1][1].shape == (6, 8, 3)                 # grey files read as BGR
    assert got[6] == (None, None)
    assert src.damage() == f'{tmp_path}: 1 of its 6 frames missing or unreadable: skipped, ' \
        'the others at their times'
    assert capfd.readouterr().err == ''
    (tmp_path / 'notes.txt').write_text('not an image')          # other files are ignored
    assert VideoFileSource(str(tmp_path), 100.0).open().read()[1] is not None


def test_a_scene_written_from_no_frame_is_refused(tmp_path):
    """render_balls' frames are an iterator: written a second time they were none, and the
    scene's rig named videos that were never written (a walk-through, 6 Dec 2026)."""
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 8, 6, 100.0)
    frames = iter([(0.0, k, np.full((6, 8, 3), 60, np.uint8)) for k in range(2)])
    synth.write_scene(str(tmp_path / 'avi'), rig_path, frames, None)
    with pytest.raises(ValueError, match='no frame given .* consumed once'):
        synth.write_scene(str(tmp_path / 'png'), rig_path, frames, None, fmt='png')
    assert not (tmp_path / 'png' / 'rig.yaml').exists()


def test_folders_of_images_numbered_from_different_starts_are_named(tmp_path):
    """cam1's first three images lost: its image 3 was its frame 0, timed 3 frames early,
    and with time_offset 0 the track was 98 mm RMS off, exit 0 (a new user's walk-through,
    6 Dec 2026). Both readers name the two starts and the time_offset that makes up for
    them; a camera whose time_offset already does is not named."""
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 8, 6, 100.0)
    for k, numbers in ((0, range(6)), (1, range(3, 6))):
        (tmp_path / f'cam{k}').mkdir()
        for i in numbers:
            cv2.imwrite(str(tmp_path / f'cam{k}' / f'img_{i:06d}.png'),
                        np.full((6, 8), i, np.uint8))
    rig = load_rig(rig_path)
    for k, cam in enumerate(rig.cameras):
        cam.source, cam.time_offset = str(tmp_path / f'cam{k}'), 0.0
    expect = ['cameras cam0 and cam1: their folders of images start at numbers 0 and 3, and '
              "each folder's first image is its camera's frame 0: if the numbers count the "
              'same instants, cam1 is timed 3 frame(s) off cam0 (time_offset -0.03 s for cam1 '
              'says so)']
    notes = []
    assert file_sources_error(rig, notes) == '' and notes == expect
    notes = []
    assert len(list(file_frames(rig, notes))) == 9 and notes == expect
    rig.cameras[1].time_offset = -0.03
    notes = []
    assert file_sources_error(rig, notes) == '' and notes == []


def test_a_camera_whose_video_ends_early_is_named(tmp_path):
    """cam1 stopped after 12 of cam0's 20 frames: past its end the ball has one camera and
    no 3-D state, and 4 of 10 balls were lost without a word (a new user's walk-through,
    6 Dec 2026). Both readers name it; files a few frames apart are not named."""
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 100.0)
    for name, short in (('far', 12), ('near', 17)):
        frames = [(None, k, np.full((48, 64, 3), 10 * n, np.uint8))
                  for n in range(20) for k in range(2) if k == 0 or n < short]
        rig = load_rig(synth.write_scene(str(tmp_path / name), rig_path, frames, None))
        notes = []
        assert file_sources_error(rig, notes) == ''
        read = []
        assert len(list(file_frames(rig, read))) == 20 + short
        if short == 12:
            assert notes == read == [
                "camera cam1: its 12 frames (0.12 s) end before camera cam0's 20 (0.20 s): "
                'after 0.12 s the ball is seen by one camera fewer (with two cameras, no 3-D '
                'state; a camera stopped early?)']
        else:
            assert notes == read == []


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


def test_an_image_sequence_with_a_gap_is_named_without_a_header(tmp_path):
    # A PNG pattern missing its 11th image: it was said to have ended 'after 10 of the 20
    # frames its header declares' (a new user's walk-through); image files have no header.
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 100.0)
    frames = [(None, k, np.full((48, 64, 3), 10 * n + 20, np.uint8))
              for n in range(20) for k in range(2)]
    rig = load_rig(synth.write_scene(str(tmp_path / 'video'), rig_path, frames, None,
                                     fmt='png'))
    (tmp_path / 'video' / 'cam0' / '000010.png').unlink()
    notes = []
    read = sum(k == 0 for _, k, _ in file_frames(rig, notes))
    assert read == 10
    assert notes == [f"camera cam0: {tmp_path / 'video' / 'cam0' / '%06d.png'}: image "
                     'sequence ended after 10 images, at a gap in their numbers (the images '
                     'after it are not read)']


def overwrite_avi_frame(path, n, seed=0):
    """Overwrite frame ``n`` of the AVI file ``path`` (its chunk in the movi list, header and
    JPEG data) with random bytes, as a damaged disk or copy does in the middle of a file."""
    data = bytearray(path.read_bytes())
    pos = data.index(b'movi')
    for _ in range(n + 1):
        pos = data.index(b'00dc', pos + 1)
    size = 8 + int.from_bytes(data[pos + 4:pos + 8], 'little')
    data[pos:pos + size] = np.random.default_rng(seed).integers(0, 256, size, np.uint8).tobytes()
    path.write_bytes(bytes(data))


def empty_avi_frame(path, n):
    """Make frame ``n`` of the AVI file ``path`` an empty chunk, as some recorders write a
    frame the camera dropped: its movi chunk and its idx1 entry of size 0, the data it held
    left in a JUNK chunk (the file's layout and the other offsets unchanged)."""
    data = bytearray(path.read_bytes())
    pos = data.index(b'movi')
    for _ in range(n + 1):
        pos = data.index(b'00dc', pos + 1)
    size = int.from_bytes(data[pos + 4:pos + 8], 'little')
    assert size >= 8
    data[pos + 4:pos + 16] = (bytes(4) + b'JUNK' + (size - 8).to_bytes(4, 'little'))
    index = data.index(b'idx1') + 8
    entries = [e for e in range(index, len(data) - 15, 16) if data[e:e + 4] == b'00dc']
    data[entries[n] + 12:entries[n] + 16] = bytes(4)
    path.write_bytes(bytes(data))


def test_an_empty_frame_of_an_avi_is_named_and_the_others_keep_their_times(tmp_path):
    # A dropped frame recorded as an empty chunk: the decoder leaves it out without failing
    # the read.
    path = tmp_path / 'cam.avi'
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*'MJPG'), 100.0,
                             (64, 48))
    for n in range(10):
        writer.write(np.full((48, 64, 3), 20 * n + 20, np.uint8))
    writer.release()
    empty_avi_frame(path, 5)
    src = VideoFileSource(str(path), 100.0).open()
    try:
        got = [(round(t * 100), int(round(frame.mean() / 20.0)) - 1)
               for t, frame in iter(src.read, (None, None))]
        damage = src.damage()
    finally:
        src.close()
    assert got == [(n, n) for n in range(10) if n != 5]
    assert damage == (f'{path}: 1 of its 10 frames unreadable (corrupt?): skipped, the '
                      'others at their times')


def test_a_frame_overwritten_mid_file_is_named_and_the_others_keep_their_times(tmp_path):
    # FFmpeg read in file order skipped the damaged chunk without a word and OpenCV numbered
    # the frames it decoded: frames 11-19 of cam0 came at 0.10-0.18 s, a frame early each,
    # and no note (19 of the 20 declared frames is within a frame's slack).
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 100.0)
    frames = [(None, k, np.full((48, 64, 3), 10 * n + 20, np.uint8))
              for n in range(20) for k in range(2)]
    rig = load_rig(synth.write_scene(str(tmp_path / 'video'), rig_path, frames, None))
    cam0 = tmp_path / 'video' / 'cam0.avi'
    overwrite_avi_frame(cam0, 10)
    notes = []
    got = [(round(t * 100), int(round(frame.mean()))) for t, k, frame in file_frames(rig, notes)
           if k == 0]
    assert [n for n, _ in got] == [n for n in range(20) if n != 10]
    assert all(abs(grey - (10 * n + 20)) <= 2 for n, grey in got)
    assert notes == [f'camera cam0: {cam0}: 1 of its 20 frames unreadable (corrupt?): '
                     'skipped, the others at their times']


@pytest.mark.parametrize('fourcc', ['MJPG', 'XVID', 'MPEG'])
def test_a_whole_avi_read_through_its_index_gives_every_frame_at_its_time(tmp_path, fourcc):
    # Read through the index, a whole file gives the frames a read in file order gives, at
    # n / fps. A frame's number is its PTS from the first frame's: MPEG-1 in AVI numbers its
    # frames from 1 (every frame was timed a frame late, the first counted as unreadable).
    path = str(tmp_path / f'{fourcc}.avi')
    writer = cv2.VideoWriter(path, cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*fourcc), 100.0,
                             (64, 48))
    assert writer.isOpened(), fourcc
    for n in range(20):
        frame = np.full((48, 64, 3), 40, np.uint8)
        frame[10:20, 2 + 3 * n:12 + 3 * n] = 230
        writer.write(frame)
    writer.release()
    plain = cv2.VideoCapture(path)
    in_file_order = [frame for ok, frame in iter(plain.read, (False, None))]
    plain.release()
    src = VideoFileSource(path, 100.0).open()
    try:
        assert src.by_index
        got = list(iter(src.read, (None, None)))
    finally:
        src.close()
    assert len(in_file_order) == 20
    assert [round(t * 100) for t, _ in got] == list(range(20))
    assert all(np.array_equal(a, b) for (_, a), b in zip(got, in_file_order, strict=True))
    assert src.damage() == ''


def test_video_files_at_different_rates_are_refused_naming_both(tmp_path):
    # The rig has one fps: cam1's 80 fps frames were timed at 100 fps and drifted off cam0's
    # (a warning on the rig's fps, then no point and a warning blaming the poses, exit 0).
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 100.0)
    frames = [(None, k, np.full((48, 64, 3), 60, np.uint8)) for n in range(3) for k in range(2)]
    rig = load_rig(synth.write_scene(str(tmp_path / 'video'), rig_path, frames, None))
    assert file_sources_error(rig) == ''
    cam0, cam1 = (str(tmp_path / 'video' / f'cam{k}.avi') for k in range(2))
    writer = cv2.VideoWriter(cam1, cv2.VideoWriter_fourcc(*'MJPG'), 80.0, (64, 48))
    for _ in range(3):
        writer.write(frames[0][2])
    writer.release()
    expect = (f'cameras cam0 and cam1 run at different rates: {cam0} is 100 fps, {cam1} 80 fps '
              '(the rig has one fps for all its cameras: record them at one rate)')
    with pytest.raises(OSError) as refused:
        list(file_frames(rig, []))
    assert str(refused.value) == expect
    assert file_sources_error(rig) == expect
    # Neither file at the rig's rate (a phone's slow motion states 30 fps for 240): the rig's
    # fps times both, as it says; each file is named in a warning, nothing refused.
    rig.fps = 240.0
    assert file_sources_error(rig) == ''


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


@pytest.mark.parametrize('path, words', [
    ('/dev/null', r'/dev/null is no V4L2 device \(a character device of major 1, video devices '
                  r'are 81'),
    ('REGULAR', r'is no V4L2 device \(a regular file; a camera is a character device')])
def test_a_path_that_is_no_video_device_is_refused_in_one_line(tmp_path, capfd, path, words):
    # /dev/null or a regular file: OpenCV tried to open it every second, with its own warning
    # and 'V4L2 device cannot be opened' (a new user's walk-through, 6 Dec 2026).
    if path == 'REGULAR':
        path = str(tmp_path / 'video0')
        open(path, 'w').close()
    src = V4L2Source(path, reopen_interval=0.0)
    with pytest.raises(OSError, match=words):
        src.open()
    assert 'WARN' not in capfd.readouterr().err
    assert sources.device_error('/dev/video_tt_absent') == ''   # may be plugged in later


def test_a_device_that_cannot_be_opened_says_why(monkeypatch):
    # Taken for a video device, /dev/null: without the permission to open it, that is said
    # (OpenCV is not asked); a device that opens but not for OpenCV, the errno of opening it,
    # else the likely causes.
    monkeypatch.setattr(sources, 'device_error', lambda path: '', raising=False)
    monkeypatch.setattr(sources.os, 'access', lambda path, mode: False)
    with pytest.raises(OSError, match='/dev/null: permission denied .*group of the device'):
        V4L2Source('/dev/null').open()
    monkeypatch.setattr(sources.os, 'access', lambda path, mode: True)
    with pytest.raises(OSError, match=r'/dev/null: V4L2 device cannot be opened: busy \('
                                      r'another program streams from it\? fuser /dev/null'):
        V4L2Source('/dev/null').open()

    def busy(path, flags):
        raise OSError(errno.EBUSY, os.strerror(errno.EBUSY))

    monkeypatch.setattr(sources.os, 'open', busy)
    with pytest.raises(OSError, match='/dev/null: V4L2 device cannot be opened: Device or '
                                      'resource busy'):
        V4L2Source('/dev/null').open()


class DriverCapture:
    """An OpenCV V4L2 capture whose driver gives ``gives`` ({property: value}) whatever it is
    asked (``asked`` records the settings)."""

    def __init__(self, gives):
        self.gives = gives
        self.asked = {}

    def isOpened(self):   # noqa: N802 (cv2.VideoCapture's name)
        return True

    def set(self, prop, value):
        self.asked[prop] = value
        return False

    def get(self, prop):
        return float(self.gives.get(prop, 0.0))

    def release(self):
        pass


@pytest.mark.parametrize('asked, gives, mismatch', [
    ((640, 480, 150.0, 'MJPG'), (1280, 720, 30.0, 'YUYV'),
     "/dev/null: the driver gives 1280x720 (asked 640x480), YUYV (asked MJPG), 30 fps (asked "
     "the rig's 150: set the rig's fps to the cameras' rate)"),
    ((640, 480, 150.0, 'MJPG'), (640, 480, 150.0, 'MJPG'), ''),
    ((0, 0, 30.0, ''), (1280, 720, 30.0, 'YUYV'), ''),    # size and format not asked
    ((640, 480, 60.0, 'MJPG'), (0, 0, 0.0, ''), '')])      # a driver that says nothing
def test_what_the_driver_gives_is_read_back_after_opening(monkeypatch, asked, gives, mismatch):
    # The node asked the device for the rig's fps and never read back what the driver took:
    # a 30 fps camera in a rig of 150 gave no state and no word.
    width, height, fps, fourcc = gives
    capture = DriverCapture({cv2.CAP_PROP_FRAME_WIDTH: width,
                             cv2.CAP_PROP_FRAME_HEIGHT: height, cv2.CAP_PROP_FPS: fps,
                             cv2.CAP_PROP_FOURCC: int.from_bytes(fourcc.encode(), 'little')})
    monkeypatch.setattr(sources, 'device_error', lambda path: '', raising=False)
    monkeypatch.setattr(sources.cv2, 'VideoCapture', lambda device, api: capture)
    w, h, f, c = asked
    src = V4L2Source('/dev/null', width=w, height=h, fps=f, fourcc=c).open()
    assert src.status == '/dev/null: opened' and src.mismatch == mismatch
    assert src.driver_fps == fps and src.driver_size == (width, height)
    assert (cv2.CAP_PROP_FRAME_WIDTH in capture.asked) == (w > 0)


def test_a_video_without_a_frame_is_refused_naming_it(tmp_path):
    """cam1's file is a valid AVI of 0 frames (a recording that never started): the node's
    start-up check and tt-perceive's reader name it; both ran with no word and no state (a
    new user's walk-through, 29 Nov 2026)."""
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 100.0)
    frames = [(None, k, np.full((48, 64, 3), 60, np.uint8)) for n in range(3) for k in range(2)]
    rig = load_rig(synth.write_scene(str(tmp_path / 'video'), rig_path, frames, None))
    cam1 = str(tmp_path / 'video' / 'cam1.avi')
    cv2.VideoWriter(cam1, cv2.VideoWriter_fourcc(*'MJPG'), 100.0, (64, 48)).release()
    expect = f'camera cam1: {cam1}: no frame can be read (an empty or broken video)'
    assert file_sources_error(rig) == expect
    with pytest.raises(OSError) as refused:
        list(file_frames(rig, []))
    assert str(refused.value) == expect


def test_a_video_of_any_name_is_read_and_a_single_image_refused(tmp_path):
    """A video named .m4v (or any name that is a file) was taken for an image topic and
    refused; one image given for a camera was read as a video of one frame at FFmpeg's
    25 fps, refused as running at another rate than the other camera (a new user's
    walk-through, 6 Dec 2026)."""
    rig_path = synth.make_rig(str(tmp_path / 'calib'), 64, 48, 100.0)
    frames = [(None, k, np.full((48, 64, 3), 60, np.uint8)) for n in range(3) for k in range(2)]
    rig = load_rig(synth.write_scene(str(tmp_path / 'video'), rig_path, frames, None))
    video = tmp_path / 'video'
    (video / 'cam1.avi').rename(video / 'cam1.m4v')
    (video / 'cam0.avi').rename(video / 'cam0_recording')
    rig.cameras[0].source, rig.cameras[1].source = 'cam0_recording', 'cam1.m4v'
    assert [source_kind(c.source, str(video)) for c in rig.cameras] == ['file', 'file']
    assert file_sources_error(rig) == ''
    assert len(list(file_frames(rig, []))) == 6
    cv2.imwrite(str(video / 'frame_000000.png'), frames[1][2])
    rig.cameras[1].source = 'frame_000000.png'
    expect = (f"camera cam1: {video / 'frame_000000.png'}: a single image, not a video (give "
              "the folder of the camera's images, or a printf pattern such as "
              'frame_%06d.jpg)')
    assert file_sources_error(rig) == expect
    with pytest.raises(OSError) as refused:
        list(file_frames(rig, []))
    assert str(refused.value) == expect


@pytest.mark.parametrize('names', [['img_1.png', 'img_1000000.png', 'img_2000000.png'],
                                   ['0.png', '33.png', '66.png', '99.png', '132.png'],
                                   ['a_001.png', 'a_002.png', 'b_001.png']])
def test_a_folder_whose_numbers_are_no_frame_counts_is_read_in_name_order(tmp_path, names):
    """Stamps in the names (more than half the numbers missing) or one number twice: the
    images are the frames in name order, digits compared as numbers (33 before 132), none
    lost (numbers taken as frame counts made a million lost frames of three images), and
    the reader says so."""
    for i, name in enumerate(names):
        cv2.imwrite(str(tmp_path / name), np.full((6, 8, 3), 10 * i, np.uint8))
    src = VideoFileSource(str(tmp_path), 100.0).open()
    got = [src.read() for _ in range(len(names) + 1)]
    assert [t for t, _ in got[:-1]] == pytest.approx(np.arange(len(names)) * 0.01)
    assert [int(f[0, 0, 0]) for _, f in got[:-1]] == [10 * i for i in range(len(names))]
    assert got[-1] == (None, None) and src.damage() == ''
    camera = load_rig(synth.make_rig(str(tmp_path / 'calib'), 8, 6, 100.0)).cameras[0]
    error, warning = VideoFileSource(str(tmp_path), 100.0).open().disagreement(camera, 100.0)
    assert error == '' and 'read in name order' in warning
