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


def test_shading_and_a_contact_shadow_do_not_move_the_centre():
    """Overhead light: a bright top, an underside dimmer than the threshold in grey but of
    another colour than the blue table, and a shadow below it: the centre stays the disc's."""
    table = (95, 60, 25)
    d = BallDetector(DetectorConfig(colour='white'))
    d.detect(np.full((120, 160, 3), table, np.uint8))
    centre, radius = np.array([80.3, 60.6]), 6.0
    ss = 8                                                 # supersampled rendering
    ys, xs = np.mgrid[0:120 * ss, 0:160 * ss]
    dx, dy = (xs + 0.5) / ss - 0.5 - centre[0], (ys + 0.5) / ss - 0.5 - centre[1]
    inside = dx ** 2 + dy ** 2 < radius ** 2
    lit = np.clip(-dy / radius, 0.0, 1.0)                  # Lambert with light from image-up
    ball = (0.3 + 0.7 * lit)[..., None] * np.array([235.0, 238.0, 240.0])
    shadow = 1.0 - 0.5 * np.exp(-0.5 * (dx ** 2 + (dy - radius) ** 2) / radius ** 2)
    image = np.where(inside[..., None], ball, np.array(table, float) * shadow[..., None])
    frame = image.reshape(120, ss, 160, ss, 3).mean(axis=(1, 3)).round().astype(np.uint8)
    grey_under = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)[int(centre[1] + 4), int(centre[0])]
    assert abs(int(grey_under) - 54) < 22            # the underside: invisible in grey alone
    found = d.detect(frame)
    assert len(found) == 1
    # A sixth of the radius on the mixed shadow/underside outline pixels; the lit cap's own
    # centroid is a quarter radius (1.5 px) above the centre.
    assert np.hypot(found[0].u - centre[0], found[0].v - centre[1]) < 0.3
