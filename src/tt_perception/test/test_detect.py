"""Ball detector on drawn discs: sub-pixel centre, motion blur, size gate, window, and a ball
against a background as bright as itself."""

import cv2
import numpy as np
from tt_perception.detect import BallDetector, DetectorConfig

BACKGROUND = 60


def disc(image, centre, radius, value=230):
    """Anti-aliased disc (1/16 pixel positions)."""
    cv2.circle(image, tuple(int(round(c * 16)) for c in centre), int(round(radius * 16)),
               (value, value, value), -1, cv2.LINE_AA, shift=4)
    return image


def detector():
    d = BallDetector(DetectorConfig(colour='white'))
    d.detect(np.full((120, 160, 3), BACKGROUND, np.uint8))       # learns the background
    return d


def test_sub_pixel_centre_of_a_ball():
    d = detector()
    for centre in [(40.3, 50.7), (101.55, 33.25), (80.0, 80.9)]:
        found = d.detect(disc(np.full((120, 160, 3), BACKGROUND, np.uint8), centre, 5.0))
        assert len(found) == 1
        assert np.hypot(found[0].u - centre[0], found[0].v - centre[1]) < 0.05
        # The diameter, plus up to 2 px of anti-aliased edge brighter than the threshold.
        assert 10.0 <= found[0].width <= 12.0 and found[0].hidden == 0.0


def test_motion_blur_keeps_the_mid_exposure_centre_and_the_width():
    d = detector()
    path = np.linspace([50.0, 60.0], [74.0, 66.0], 9)          # 25 px streak
    blurred = np.mean([disc(np.full((120, 160, 3), BACKGROUND, np.float32), p, 4.0)
                       for p in path], axis=0).astype(np.uint8)
    found = d.detect(blurred)
    assert len(found) == 1
    assert np.hypot(found[0].u - 62.0, found[0].v - 63.0) < 0.2
    assert 8.0 <= found[0].width <= 10.0            # across the motion: the diameter


def test_large_object_and_static_things_are_not_balls():
    d = BallDetector(DetectorConfig(colour='white', max_width=20.0))
    scene = disc(np.full((120, 160, 3), BACKGROUND, np.uint8), (20.0, 20.0), 4.0)  # lies still
    d.detect(scene)
    assert d.detect(disc(scene.copy(), (90.0, 60.0), 18.0)) == []        # racket-sized


def test_search_window_and_a_blob_cut_by_it():
    d = detector()
    frame = disc(np.full((120, 160, 3), BACKGROUND, np.uint8), (70.0, 60.0), 5.0)
    assert len(d.detect(frame, roi_centre=(75.0, 62.0), update_background=False)) == 1
    assert d.detect(frame, roi_centre=(130.0, 60.0), update_background=False) == []
    # The window's edge through the ball: not measured (its centre would be biased).
    assert d.detect(frame, roi_centre=(110.0, 60.0), update_background=False) == []


def test_ball_over_a_white_line_is_flagged():
    d = BallDetector(DetectorConfig(colour='white'))
    background = np.full((120, 160, 3), BACKGROUND, np.uint8)
    cv2.line(background, (0, 62), (159, 62), (230, 230, 230), 3)
    d.detect(background)
    found = d.detect(disc(background.copy(), (80.0, 57.0), 5.0))
    assert len(found) == 1 and found[0].hidden > 0.05
    assert found[0].v < 57.0 - 0.2        # the part over the line is lost: biased centre
