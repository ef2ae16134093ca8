"""Ball detector on drawn discs: sub-pixel centre, motion blur, size gate, window, a ball
against a background as bright as itself, and the fit of the expected outline to lit balls
half as dark as the table."""

import cv2
import numpy as np
import pytest
from tt_perception.detect import (
    BallDetector,
    BallImage,
    DetectorConfig,
    _outline_extent,
    _whiten,
    exposure_level,
    light_gains,
)
from tt_perception.pipeline import ball_image

from tt_perception import synth

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
    # Along it, a disc of radius r swept over b px has variance r^2 / 4 + b^2 / 12: the
    # measure sqrt(4 r^2 + 4 b^2 / 3) (29.7 px), less the faint ends under the threshold,
    # plus the anti-aliased edge (as the width's).
    along = np.sqrt(4 * 4.0 ** 2 + 4 * np.hypot(24.0, 6.0) ** 2 / 3)
    assert 0.85 * along < found[0].bright_length < along + 2.0


def test_large_object_and_static_things_are_not_balls():
    d = BallDetector(DetectorConfig(colour='white', max_width=20.0))
    scene = disc(np.full((120, 160, 3), BACKGROUND, np.uint8), (20.0, 20.0), 4.0)  # lies still
    d.detect(scene)
    assert d.detect(disc(scene.copy(), (90.0, 60.0), 18.0)) == []        # racket-sized


def test_the_largest_ball_follows_the_cameras_focal_length():
    # A ball 40 mm across 1.0 m from a 1920 x 1080 camera with a 60 degree lens (focal
    # length 1663 px) is 2 r f / d = 66.5 px wide. Sized in pixels for a 640 x 480 camera
    # (30 px), it was refused: synth's hall at 1920 x 1080 lost a ball's last 15 frames, as
    # it came to the robot. Through a 640 x 480 camera (554 px) a blob that size would be a
    # ball 0.33 m away, nearer than NEAREST_BALL_M: refused, as before.
    focal_1080p = 960.0 / np.tan(np.radians(30.0))
    radius_px = 0.02 * focal_1080p / 1.0
    background = np.full((200, 240, 3), BACKGROUND, np.uint8)
    ball = disc(background.copy(), (120.3, 100.6), radius_px)
    near = BallDetector(DetectorConfig(colour='white'), focal=focal_1080p)
    near.detect(background)
    found = near.detect(ball)
    assert len(found) == 1 and np.hypot(found[0].u - 120.3, found[0].v - 100.6) < 0.1
    far = BallDetector(DetectorConfig(colour='white'), focal=554.256)
    far.detect(background)
    assert far.detect(ball) == []


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


@pytest.mark.parametrize('change, kept, sure', [
    ((+40, +60, +205), True, True),       # an orange ball: red well above blue
    ((+45, +46, +54), True, False),       # a small orange ball whose chroma JPEG washed out
    ((+60, +30, +5), False, False),       # bluish: not an orange ball, whatever its size
], ids=['orange', 'washed-out', 'bluish'])
def test_a_washed_out_orange_blob_is_kept_but_not_sure_of_its_colour(change, kept, sure):
    """In orange mode a blob of the ball's colour is a sure candidate; one whose colour only
    does not contradict it (grey, adding red at least as much as blue and green) is kept,
    marked not sure (the pipeline pairs it only with a camera that is sure); a colour that
    does contradict it is dropped."""
    table = np.array([95, 60, 25], np.uint8)                   # B, G, R
    d = BallDetector(DetectorConfig(colour='orange'))
    frame = np.tile(table, (120, 160, 1))
    d.detect(frame.copy())
    colour = tuple(int(c) for c in np.clip(table.astype(int) + change, 0, 255))
    cv2.circle(frame, (80, 60), 5, colour, -1)
    found = d.detect(frame)
    assert len(found) == int(kept)
    if kept:
        assert found[0].colour_sure is sure and abs(found[0].u - 80) < 0.5


@pytest.mark.parametrize('colour, kept', [
    ((30, 75, 130), True),        # an orange ball in the hall's light, darker than the line
    ((100, 100, 100), False),     # a grey thing
    ((95, 60, 25), False),        # the blue table's colour
], ids=['orange', 'grey', 'blue'])
def test_an_orange_ball_in_front_of_a_white_line_is_kept_but_not_sure(colour, kept):
    """An orange ball under the hall's light is dimmer than a white line in every channel
    (its red 130 against the line's 164): in front of the line, its few pixels blurred
    together with the line's (optics, JPEG's halved chroma resolution), it darkens the blue
    most and the red least, so it adds no red at all. With up to half the line's colour
    taken out of the blob's it is orange (detect's _orange_mixed): kept, not sure. A grey
    thing, or a blue one, that darkens the line is no orange ball however mixed."""
    line = np.array([190, 177, 164], np.float32)                       # B, G, R
    d = BallDetector(DetectorConfig(colour='orange'))
    d.detect(np.tile(line.astype(np.uint8), (120, 160, 1)))
    ss = 8                                                 # supersampled rendering
    ys, xs = np.mgrid[0:120 * ss, 0:160 * ss]
    inside = ((xs + 0.5) / ss - 0.5 - 80.0) ** 2 + ((ys + 0.5) / ss - 0.5 - 60.0) ** 2 < 16.0
    image = np.where(inside[..., None], np.array(colour, np.float32), line)
    frame = image.reshape(120, ss, 160, ss, 3).mean(axis=(1, 3))
    frame = cv2.GaussianBlur(frame, (0, 0), 1.5).round().astype(np.uint8)
    found = d.detect(frame)
    assert len(found) == int(kept)
    if kept:
        assert not found[0].colour_sure and np.hypot(found[0].u - 80.0, found[0].v - 60.0) < 0.5


def streaked_disc(table, colour, start, end, radius, steps=24):
    """A disc of ``colour`` (B, G, R) swept from ``start`` to ``end`` over a ``table``
    background during the exposure: the mean of its images along the path (120 x 160)."""
    frames = [cv2.circle(np.tile(np.asarray(table, np.float32), (120, 160, 1)),
                         tuple(int(round(c * 16)) for c in p), int(round(radius * 16)),
                         tuple(float(c) for c in colour), -1, cv2.LINE_AA, shift=4)
              for p in np.linspace(start, end, steps)]
    return np.rint(np.mean(frames, axis=0)).astype(np.uint8)


@pytest.mark.parametrize('colour, path, white', [
    ((230, 230, 230), ((55.0, 50.0), (85.0, 65.0)), True),   # the blue table shows through
    ((40, 120, 230), ((55.0, 50.0), (85.0, 65.0)), False),   # an orange ball, the same way
    ((120, 150, 200), ((70.0, 57.5), (70.0, 57.5)), False),  # skin, held still
], ids=['white', 'orange', 'skin'])
def test_a_white_ball_streaked_over_a_blue_table_is_white(colour, path, white):
    """A ball swept over three times its diameter in the exposure covers each pixel for a
    part of it only, so its pixels mix in the table's blue: their mean colour is not
    balanced enough to be white, but with some of the table's colour taken out it is
    (detect's _white_mixed). An orange ball streaked the same way, or a reddish thing
    held still, is not. (A reddish thing streaked over blue mixes to grey: no colour test
    can tell it from a dimmer white ball.)"""
    table = (95, 60, 25)
    d = BallDetector(DetectorConfig(colour='white'))
    d.detect(np.tile(np.array(table, np.uint8), (120, 160, 1)))
    frame = streaked_disc(table, colour, *path, 5.0)
    found = d.detect(frame)
    if white:
        # The case meant: the brighter half of the streak's pixels, as a mean, is not white.
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        changed = np.abs(grey.astype(int) - int(np.mean(table) + 0.5)) > 22
        lit = changed & (grey >= np.median(grey[changed]))
        mean = frame[lit].mean(axis=0)
        assert mean.min() < 0.72 * mean.max()
        assert len(found) == 1 and found[0].colour_sure
        assert np.hypot(found[0].u - 70.0, found[0].v - 57.5) < 0.5
    else:
        assert found == []


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


def grey_disc_on(floor, value, centre, radius, ss=8):
    """A disc of grey ``value`` on a plain ``floor`` (B, G, R), 120 x 160, anti-aliased with
    ``ss`` x ``ss`` samples a pixel."""
    ys, xs = np.mgrid[0:120 * ss, 0:160 * ss]
    inside = np.hypot((xs + 0.5) / ss - 0.5 - centre[0],
                      (ys + 0.5) / ss - 0.5 - centre[1]) < radius
    image = np.where(inside[..., None], float(value), np.array(floor, float))
    return image.reshape(120, ss, 160, ss, 3).mean(axis=(1, 3)).round().astype(np.uint8)


def test_a_ball_as_grey_as_the_floor_behind_it_is_found_by_its_colour():
    """A white ball in the shade (86 in every channel) before a brown floor of the same grey
    level: no pixel changes its grey by the threshold, two channels change by 54-56. Its
    centre and width are those of the disc (anti-aliased, 8 x 8 samples a pixel)."""
    floor, centre, radius = (30, 70, 140), np.array([70.4, 55.7]), 5.0
    cfg = DetectorConfig(colour='any')
    d = BallDetector(cfg)
    d.detect(np.full((120, 160, 3), floor, np.uint8))
    frame = grey_disc_on(floor, 86, centre, radius)
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY).astype(int)
    assert np.abs(grey - grey[0, 0]).max() < cfg.diff_threshold
    found = d.detect(frame)
    assert len(found) == 1
    assert np.hypot(found[0].u - centre[0], found[0].v - centre[1]) < 0.3
    assert abs(found[0].width - 2 * radius) < 0.5      # the silhouette's: the diameter


def test_a_ball_seen_in_grey_by_a_sliver_is_completed_by_its_colour():
    """A white ball lit weakly from above before a red-brown floor as grey as its shaded
    side (69): three pixels of its lit top (130) change in grey, fewer than a blob's least
    area, the rest only in colour. It is found whole, and white by its lit top (its mean over
    the whole ball, about 72, is too dark for a white ball)."""
    floor, centre, radius = (10, 50, 130), np.array([90.6, 60.2]), 6.0
    cfg = DetectorConfig(colour='white')
    d = BallDetector(cfg)
    d.detect(np.full((120, 160, 3), floor, np.uint8))
    frame = grey_disc_on(floor, 69, centre, radius)
    top = int(np.ceil(centre[1] - radius))                     # the disc's top full row
    frame[top + 1, 90:93] = 130
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY).astype(int)
    assert np.count_nonzero(np.abs(grey - grey[0, 0]) > cfg.diff_threshold) < cfg.min_area
    found = d.detect(frame)
    assert len(found) == 1 and found[0].colour_sure
    assert np.hypot(found[0].u - centre[0], found[0].v - centre[1]) < 0.3


TABLE = np.array([95.0, 60.0, 25.0])
WHITE = np.array([235.0, 238.0, 240.0])


def lit_ball(centre, radius, blur, light, size=(60, 80), ss=8, steps=16):
    """A white ball on the blue table, lit by a distant light along ``light`` (image right,
    image down, away from the camera) with nothing else: the side turned away from it is as
    dark as the table. Rendered here, independently of the detector: ``ss`` x ``ss`` samples
    per pixel, ``steps`` positions over the exposure along ``blur`` (px)."""
    h, w = size
    ys, xs = np.mgrid[0:h * ss, 0:w * ss]
    px, py = (xs + 0.5) / ss - 0.5, (ys + 0.5) / ss - 0.5
    light = np.asarray(light, float) / np.linalg.norm(light)
    acc = np.zeros((h * ss, w * ss, 3))
    for s in (np.arange(steps) + 0.5) / steps - 0.5:
        dx = (px - centre[0] - s * blur[0]) / radius
        dy = (py - centre[1] - s * blur[1]) / radius
        inside = dx * dx + dy * dy < 1.0
        dz = -np.sqrt(np.clip(1.0 - dx * dx - dy * dy, 0.0, 1.0))     # toward the camera
        lit = np.clip(dx * light[0] + dy * light[1] + dz * light[2], 0.0, 1.0)
        acc += np.where(inside[..., None], TABLE + lit[..., None] * (WHITE - TABLE), TABLE)
    image = (acc / steps).reshape(h, ss, w, ss, 3).mean(axis=(1, 3))
    return image.round().astype(np.uint8)


def fitted_and_plain_errors(light, radii=(3.0, 4.0, 6.0), n=5, seed=0, curvature_weight=0.0):
    """Errors (px) of the outline fit and of the plain (silhouette) centre on lit balls at
    sub-pixel centres, blurred by a radius along random directions; the fit's penalty on the
    brightness's curvature is ``curvature_weight`` (:class:`DetectorConfig`). The renders
    are sharp (no camera blur): the detector is told so (``image_blur`` 0)."""
    rng = np.random.default_rng(seed)
    fitted, plain = [], []
    for radius in radii:
        for _ in range(n):
            centre = np.array([40.0, 30.0]) + rng.uniform(0.0, 1.0, 2)
            angle = rng.uniform(0.0, np.pi)
            blur = radius * np.array([np.cos(angle), np.sin(angle)])
            frame = lit_ball(centre, radius, blur, light)
            d = BallDetector(DetectorConfig(colour='any', curvature_weight=curvature_weight,
                                            image_blur=0.0))
            d.detect(np.full_like(frame, TABLE.astype(np.uint8)))
            found = d.detect(frame, update_background=False)
            # The prediction is a third of a pixel off; the outline and blur are exact.
            expected = BallImage(centre[0] + 0.3, centre[1] - 0.3, np.eye(2) * radius, blur)
            fit = d.detect(frame, update_background=False, expected=expected)
            assert len(found) == 1 and len(fit) == 1 and fit[0].fitted
            plain.append((found[0].u - centre[0], found[0].v - centre[1]))
            fitted.append((fit[0].u - centre[0], fit[0].v - centre[1]))
    return np.array(fitted), np.array(plain)


@pytest.mark.parametrize('light', [(0.0, -1.0, 0.0), (-1.0, 0.0, 0.0), (1.0, -1.0, 0.0)])
def test_outline_fit_where_half_the_ball_is_as_dark_as_the_background(light):
    """Half the ball turned away from a single light, with no ambient light, is the table's
    colour: the silhouette's centroid leans a quarter of the ball toward the light; the fit of
    the known outline with a free quadratic brightness finds the centre within a tenth of a
    pixel, whatever the light's direction in the image. The default penalty on the
    brightness's curvature, which such a sharp terminator needs, costs about half a pixel
    toward the light (measured 0.42-0.45 px; 0.46-0.50 px with the pixels inside the ball
    weighted by the fit's residuals, ``inside_huber``, which weights down the terminator the
    penalised shading cannot follow; docs/perception_measured.md)."""
    fitted, plain = fitted_and_plain_errors(light)
    assert np.abs(fitted).max() < 0.1
    assert np.hypot(*plain.T).min() > 1.0
    default = DetectorConfig().curvature_weight
    penalised, _ = fitted_and_plain_errors(light, curvature_weight=default)
    assert np.abs(penalised).max() < 0.55
    toward = np.asarray(light[:2]) / np.linalg.norm(light[:2])
    assert penalised.mean(axis=0) @ toward > 0.05       # the bias is toward the light


def test_outline_fit_with_light_toward_the_camera_keeps_a_small_bias():
    """A light with a part toward the camera brightens the ball's middle more than a quadratic
    over the image follows near the outline: the fit's measured bias there is about a tenth of
    a pixel (docs/perception.md), against a pixel for the silhouette's centroid; a quarter of
    a pixel with the default penalty on the brightness's curvature."""
    fitted, plain = fitted_and_plain_errors((0.5, -1.0, -1.0))
    assert np.abs(fitted.mean(axis=0)).max() < 0.15 and np.abs(fitted).max() < 0.25
    assert np.hypot(*plain.T).min() > 0.7
    penalised, _ = fitted_and_plain_errors(
        (0.5, -1.0, -1.0), curvature_weight=DetectorConfig().curvature_weight)
    assert np.abs(penalised).max() < 0.25


def test_expected_ball_image_is_the_projection_of_the_sphere():
    """The outline of :func:`pipeline.ball_image` against the sphere's projection, point by
    point (off the axis, through the lens distortion), and the blur against the projections of
    the positions at the start and end of the exposure."""
    rig = synth.demo_rig(1280, 720)
    cam = rig.cameras[1]
    radius = 0.02
    for position in ([0.6, 0.5, 0.4], [-1.2, -0.6, 0.1], [0.0, 0.0, 0.2]):
        position = np.array(position)
        velocity = np.array([-8.0, 1.0, 2.0])
        ball = ball_image(cam, position, velocity, radius, 2e-3)
        centre = cam.project(position[None])[0]
        assert np.hypot(ball.u - centre[0], ball.v - centre[1]) < 1e-9
        ends = cam.project(np.array([position - 1e-3 * velocity, position + 1e-3 * velocity]))
        assert np.allclose(ball.blur, ends[1] - ends[0], atol=1e-9)
        # The sphere's points, projected: their outline in each direction from the centre.
        rng = np.random.default_rng(1)
        normals = rng.normal(size=(200000, 3))
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        uv = cam.project(position + radius * normals) - centre
        a = np.linalg.inv(ball.outline @ ball.outline.T)
        for angle in np.linspace(0.0, np.pi, 12, endpoint=False):
            e = np.array([np.cos(angle), np.sin(angle)])
            reach = (uv @ e).max()                     # support of the projected sphere
            # The support of the ellipse {d: d^T a d = 1} along e.
            support = np.sqrt(e @ np.linalg.inv(a) @ e)
            assert abs(reach - support) < 0.01 * support
        # The image of the world's up at the ball: a unit vector, up the image (v falls)
        # for this camera, which looks at the table from above its edge.
        top = cam.project((position + [0.0, 0.0, 1e-4])[None])[0] - centre
        assert np.linalg.norm(ball.up) == pytest.approx(1.0)
        assert ball.up @ (top / np.linalg.norm(top)) > 0.9999 and ball.up[1] < 0.0
    # A ball whose centre is within its radius of the lens has no outline.
    inside = cam.R.T @ (np.array([0.0, 0.0, 0.5 * radius]) - cam.t)
    assert np.linalg.norm(cam.R @ inside + cam.t) < radius
    assert ball_image(cam, inside, np.zeros(3), radius, 2e-3) is None


def test_the_outlines_whitening_and_extent_against_numpys_decompositions():
    """The 2 x 2 closed forms: (M M^T)^(-1/2) against numpy's eigendecomposition, the
    largest semi-axis against the largest singular value, the mean one sqrt |det M|."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        outline = rng.normal(size=(2, 2)) * rng.uniform(0.5, 12.0)
        vals, vecs = np.linalg.eigh(outline @ outline.T)
        whitening = _whiten(outline)
        assert np.allclose(whitening, (vecs / np.sqrt(vals)) @ vecs.T, rtol=1e-9, atol=0.0)
        largest, mean = _outline_extent(outline)
        assert largest == pytest.approx(np.linalg.svd(outline, compute_uv=False)[0], rel=1e-12)
        assert mean == pytest.approx(np.sqrt(abs(np.linalg.det(outline))), rel=1e-9)
    # An outline of no area (rounding may make its determinant negative) has no whitening.
    for flat in (np.outer([0.35, 0.82], [0.33, -1.3]), np.zeros((2, 2))):
        assert np.all(np.isnan(_whiten(flat)))


@pytest.mark.parametrize('radius, image_blur', [(3.2, 0.3), (3.2, 0.6), (6.5, 0.4)])
def test_a_blurred_outline_covers_each_pixel_as_a_gaussian_blurred_disc_averaged_over_it(
        radius, image_blur):
    """With ``image_blur`` the model's coverage of a pixel is that of the disc blurred by a
    two-dimensional Gaussian of that standard deviation and averaged over the pixel's area:
    here a disc on 40 x 40 points per pixel through OpenCV's Gaussian blur (which also
    narrows the blurred disc's half-way level, by about blur^2 / (2 radius)), and the
    coverage's derivative with respect to the centre is that image's. (The model samples
    each pixel once, with the pixel's width in the Gaussian: within 2 % of a pixel, 7 % of
    the derivative's peak.)"""
    from tt_perception.detect import ball_model
    centre = np.array([10.3, 9.8])
    sub, size = 40, 21
    ys, xs = np.mgrid[0:size, 0:size]
    xs, ys = xs.ravel().astype(float), ys.ravel().astype(float)
    fine = (np.arange(size * sub) + 0.5) / sub - 0.5
    gy, gx = np.meshgrid(fine, fine, indexing='ij')

    def integrated(c):
        disc = (np.hypot(gx - c[0], gy - c[1]) < radius).astype(float)
        blurred = cv2.GaussianBlur(disc, (0, 0), image_blur * sub)
        return blurred.reshape(size, sub, size, sub).mean(axis=(1, 3)).ravel()

    ball = BallImage(centre[0], centre[1], np.eye(2) * radius, np.zeros(2))
    cover, _, dcover, _ = ball_model(xs, ys, centre, ball, image_blur=image_blur)
    truth = integrated(centre)
    assert np.abs(cover - truth).max() < 0.02
    assert abs(cover.sum() - truth.sum()) < 0.015 * truth.sum()      # the ball's area
    h = 0.05
    for axis in range(2):
        step = np.eye(2)[axis] * h
        slope = (integrated(centre + step) - integrated(centre - step)) / (2 * h)
        assert np.abs(dcover[:, axis] - slope).max() < 0.07 * np.abs(slope).max()


def top_lit_ball(centre, radius, blur, size, sub=8):
    """A ball of ``radius`` px at ``centre`` in a ``size`` x ``size`` patch, lit from above
    (brightness falling linearly from 1 at its top to 0.2 at its bottom over a background of
    0.15, times 200 grey levels), blurred by a Gaussian of ``blur`` px (none at 0) and
    averaged over each pixel: drawn on ``sub`` x ``sub`` points per pixel with OpenCV's
    Gaussian blur. Returns (the patch, its background), float."""
    fine = (np.arange(size * sub) + 0.5) / sub - 0.5
    gy, gx = np.meshgrid(fine, fine, indexing='ij')
    dy = (gy - centre[1]) / radius                         # image y down: the top is -1
    lit = np.where(np.hypot(gx - centre[0], gy - centre[1]) < radius, 0.6 - 0.4 * dy, 0.15)
    if blur > 0.0:
        lit = cv2.GaussianBlur(lit, (0, 0), blur * sub)
    grey = 200.0 * lit.reshape(size, sub, size, sub).mean(axis=(1, 3))
    return grey, np.full((size, size), 200.0 * 0.15)


def test_a_shaded_ball_blurred_by_the_camera_is_fitted_without_a_lean_at_that_blur():
    """A ball 3.2 px in radius, lit from above (brightness falling linearly from 1 at its top
    to 0.2 at its bottom over a background of 0.15), blurred by a Gaussian of 0.5 px and
    averaged over each pixel: rendered here on a grid of 8 x 8 points per pixel with
    OpenCV's Gaussian blur, at 60 sub-pixel positions. A blur spills more light past the
    outline on the bright side than on the dark one. With the camera's blur modelled at its
    true value the fitted centre does not lean (mean within 0.02 px on each axis), and the
    fit's residual is smallest at that value among 0.35, 0.5 and 0.65 px (the likelihood
    measures the blur); modelled sharp, the centre leans toward the lit top by more than
    0.08 px."""
    from tt_perception.detect import OutlineFit
    radius, blur, size = 3.2, 0.5, 24
    rng = np.random.default_rng(3)
    ball = BallImage(0.0, 0.0, np.eye(2) * radius, np.zeros(2))
    errors = {b: [] for b in (0.0, 0.35, blur, 0.65)}
    costs = dict.fromkeys(errors, 0.0)
    for _ in range(60):
        centre = 12.0 + rng.uniform(-1.0, 1.0, 2)
        grey, background = top_lit_ball(centre, radius, blur, size)
        for b in errors:
            fit = OutlineFit(grey, background, np.ones((size, size), bool), ball,
                             image_blur=b).fit((12.0, 12.0))
            errors[b].append(fit[0] - centre)
            costs[b] += fit[1]
    assert np.all(np.abs(np.mean(errors[blur], axis=0)) < 0.02), np.mean(errors[blur], axis=0)
    assert costs[blur] < min(costs[0.35], costs[0.65])
    assert np.mean(errors[0.0], axis=0)[1] < -0.08


def test_a_small_balls_bright_part_is_not_wider_than_the_ball_behind_jpeg():
    """An orange ball of 2.3 px radius lit from above, through OpenCV's JPEG at quality 30,
    at nine sub-pixel positions: the silhouette takes in the compression block's ringing
    (measured up to 1.8 times the ball's width), the bright part stays within the ball's
    width, so the pipeline's "too wide" gate (``TrackerConfig.width_ratio``, 1.9) on the
    smaller of the two keeps the ball."""
    rng = np.random.default_rng(0)

    def jpeg(image):
        ok, buffer = cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, 30])
        return cv2.imdecode(buffer, cv2.IMREAD_COLOR)

    table = np.clip(np.full((120, 160, 3), (70.0, 60.0, 50.0)) + rng.normal(0, 2, (120, 160, 3)),
                    0, 255).astype(np.uint8)
    radius, cy = 2.3, 60.3
    ys, xs = np.mgrid[0:120, 0:160]
    offsets = (np.arange(8) + 0.5) / 8 - 0.5
    widths = []
    for cx in np.linspace(70.1, 77.9, 9):
        d = BallDetector(DetectorConfig(colour='orange'))
        d.detect(jpeg(table))
        cover = np.mean([np.hypot(xs + ox - cx, ys + oy - cy) <= radius
                         for ox in offsets for oy in offsets], axis=0)[:, :, None]
        shade = np.clip(0.35 + 0.65 * (cy - ys) / radius, 0.15, 1.0)[:, :, None]
        ball = np.array([30.0, 120.0, 235.0]) * shade
        dets = d.detect(jpeg(np.clip(table * (1 - cover) + ball * cover, 0, 255)
                             .astype(np.uint8)))
        assert dets
        widths.append((dets[0].width, dets[0].bright_width))
    widths = np.array(widths) / (2 * radius)
    assert np.all(widths[:, 1] <= 1.0)


def test_the_fits_linear_solver_solves_and_names_a_singular_system():
    """The outline fit's compiled solver (it runs without the GIL, so not LAPACK's) gives
    numpy's solution on systems of its sizes, pivoting where a zero leads, and says when the
    matrix is singular (a row of zeros, two equal rows) instead of returning garbage."""
    from tt_perception.detect import _solve
    rng = np.random.default_rng(3)
    for n in (6, 8):
        for _ in range(20):
            a = rng.normal(size=(n, n))
            a = a @ a.T + 0.1 * np.eye(n)               # a normal matrix, as the fit's
            b = rng.normal(size=n)
            x, ok = _solve(a, b)
            assert ok
            np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-9, atol=1e-12)
        swapped = np.eye(n)[::-1] * 2.0                 # a zero on every diagonal entry
        x, ok = _solve(swapped, np.arange(1.0, n + 1))
        assert ok
        np.testing.assert_allclose(x, np.arange(1.0, n + 1)[::-1] / 2.0)
        singular = rng.normal(size=(n, n))
        singular[2] = 0.0
        assert not _solve(singular, np.ones(n))[1]
        singular = rng.normal(size=(n, n))
        singular[3] = singular[1]
        # Elimination of an exact copy leaves an exact zero row.
        assert not _solve(singular, np.ones(n))[1]
        # Singular in exact arithmetic, not in floating point: the Gauss-Newton matrix of
        # fewer pixels than unknowns (rank 5 of n). Its pivots come out near 1e-17, not 0.
        jac = rng.normal(size=(5, n))
        assert not _solve(jac.T @ jac, np.ones(n))[1]


def test_a_fit_on_fewer_covered_pixels_than_unknowns_is_not_posed():
    """A ball whose usable pixels it covers are fewer than the fit's unknowns (six of shading,
    two of centre) has no fitted centre (the caller keeps the blob's); with the disc's
    pixels usable the same ball is found."""
    from tt_perception.detect import fit_outline
    ys, xs = np.mgrid[0:21, 0:21]
    ball = BallImage(10.3, 9.8, np.eye(2) * 4.0, np.zeros(2))
    inside = np.hypot(xs - 10.3, ys - 9.8) < 4.0
    grey = np.where(inside, 200.0, 60.0)
    background = np.full(grey.shape, 60.0)
    usable = np.hypot(xs - 10.3, ys - 9.8) <= 6.5
    centre, _ = fit_outline(grey, background, usable, (10.0, 10.0), ball)
    np.testing.assert_allclose(centre, (10.3, 9.8), atol=0.05)
    # The background beyond its outline's pixels, and 5 of its own pixels.
    few = usable & (np.hypot(xs - 10.3, ys - 9.8) > 5.5)
    few[10, 8:13] = True
    assert fit_outline(grey, background, few, (10.0, 10.0), ball) is None


def _silhouette_by_opencv(patch, background, seed, sx, sy, threshold):
    """The silhouette's coverage centroid and second moments as the detector's docstring
    defines them, with OpenCV's connected components, erosion and box filter."""
    change = patch.astype(np.float32) - background
    size = np.abs(change).max(axis=2)
    sil = ((size > threshold) & (change.max(axis=2) >= 0.0)).astype(np.uint8)
    grown = np.zeros_like(sil)
    grown[sy:sy + seed.shape[0], sx:sx + seed.shape[1]] = seed
    sil |= grown
    _, labels = cv2.connectedComponents(sil, connectivity=8)
    region = np.isin(labels, np.unique(labels[grown > 0])).astype(np.uint8)
    interior = cv2.erode(region, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
    inner = interior.astype(np.float32)
    near_sum = cv2.boxFilter(size * inner, -1, (5, 5), normalize=False)
    near_n = cv2.boxFilter(inner, -1, (5, 5), normalize=False)
    outline = (region > 0) & (interior == 0)
    local = np.where(near_n > 0, near_sum / np.maximum(near_n, 1e-6),
                     np.median(size[grown > 0]))
    cover = inner.copy()
    cover[outline] = np.clip(size[outline] / np.maximum(local[outline], 1e-6), 0.0, 1.0)
    m = cv2.moments(cover)
    return np.array([m['m10'] / m['m00'], m['m01'] / m['m00'], m['mu20'] / m['m00'],
                     m['mu02'] / m['m00'], m['mu11'] / m['m00']])


def _blob_by_opencv(sub, diff, patch, background, px, py, threshold):
    """What ``_blob_measures`` returns, written with OpenCV's operations on the patch."""
    bh, bw = sub.shape
    weighted = cv2.moments(cv2.multiply(np.maximum(diff, 1), sub))
    total = weighted['m00']
    shape = cv2.moments(sub, binaryImage=True)
    area = shape['m00']
    grey = cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY)
    inside = np.zeros(grey.shape, np.uint8)
    inside[py:py + bh, px:px + bw] = sub
    ring = cv2.dilate(inside, np.ones((3, 3), np.uint8)) - inside
    level = int(round(cv2.mean(grey, mask=inside)[0]))
    alike = cv2.absdiff(grey, np.full_like(grey, level)) < threshold
    hidden = np.count_nonzero(alike & (ring > 0)) / max(cv2.countNonZero(ring), 1)
    box = grey[py:py + bh, px:px + bw]
    changed = (sub > 0) & (diff > threshold)
    chosen = changed if changed.any() else sub > 0
    lit = (chosen & (box >= np.median(box[chosen]))).astype(np.uint8)
    colour = cv2.mean(patch[py:py + bh, px:px + bw], mask=lit)[:3]
    under = cv2.mean(background[py:py + bh, px:px + bw], mask=lit)[:3]
    return [total, weighted['m10'] / total, weighted['m01'] / total, shape['mu20'] / area,
            shape['mu02'] / area, shape['mu11'] / area, hidden, *colour, *under]


def test_a_fit_knows_a_ball_lit_from_below():
    """A ball whose brightness grows within 60 degrees of the image of the world's down, by
    more than a tenth of its own, is lit from below; toward the side or the up, beyond 60
    degrees from the down, or with the up unknown, it is not. The brightness is the model's
    linear shading over the whitened offsets w = A d (:func:`ball_model`), so on a sheared
    outline its gradient over the pixels, A^T (s_x, s_y), is not along (s_x, s_y): the
    shading is given here by its gradient g over the pixels, (s_x, s_y) = A^-T g."""
    from tt_perception.detect import OutlineFit, ball_model
    ys, xs = np.mgrid[0:25, 0:25].astype(float)
    xs, ys = xs.ravel(), ys.ravel()
    background = np.full(xs.size, 20.0)
    down = np.array([0.3, 1.0]) / np.hypot(0.3, 1.0)          # a camera rolled a little
    across = np.array([-down[1], down[0]])
    for outline in (np.eye(2) * 3.0, np.array([[3.5, 1.5], [0.0, 2.5]])):
        a = _whiten(outline)
        cases = {55.0: True, 65.0: False, 90.0: False, 180.0: False}    # degrees from down
        for angle, below in cases.items():
            rad = np.radians(angle)
            for size, strong in ((12.0, True), (1.0, False)):   # per pixel; centre 100
                g = size * (np.cos(rad) * down + np.sin(rad) * across)
                shading = [100.0, *np.linalg.solve(a.T, g), 0.0, 0.0, 0.0]
                for up in (-down, None):
                    ball = BallImage(12.0, 12.0, outline, np.zeros(2), up)
                    cover, basis, _, _ = ball_model(xs, ys, (12.0, 12.0), ball)
                    grey = background * (1.0 - cover) + basis @ shading
                    fitter = OutlineFit(None, None, None, ball,
                                        pixels=(grey, background, xs, ys))
                    centre, _, lit_from_below = fitter.fit((12.2, 11.9))[:3]
                    np.testing.assert_allclose(centre, (12.0, 12.0), atol=0.01)
                    expected = below and strong and up is not None
                    assert lit_from_below == expected, (outline, angle, size, up)


def test_the_blobs_compiled_measures_are_their_definition():
    """A blob's weighted centroid, shape moments, bright surroundings and lit colour (one
    compiled kernel) against the same definitions written with OpenCV, on random blobs of
    several parts with noise, touching the patch's edge or not."""
    from tt_perception.detect import _blob_measures
    rng = np.random.default_rng(8)
    for _ in range(60):
        bh, bw = rng.integers(1, 12, size=2)
        px, py = rng.integers(0, 3, size=2)
        h, w = py + bh + rng.integers(0, 3), px + bw + rng.integers(0, 3)
        patch = rng.integers(0, 256, size=(h, w, 3)).astype(np.uint8)
        background = rng.uniform(0, 255, size=(h, w, 3)).astype(np.float32)
        sub = (rng.random((bh, bw)) < 0.7).astype(np.uint8)
        sub[rng.integers(bh), rng.integers(bw)] = 1
        diff = rng.integers(0, 256, size=(bh, bw)).astype(np.uint8)
        grey = cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY)
        got = _blob_measures(sub, diff, grey, patch, background, int(px), int(py), 22.0, True,
                             True)
        want = _blob_by_opencv(sub, diff, patch, background, px, py, 22.0)
        np.testing.assert_allclose(got[:10], want[:10], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got[10:], want[10:], rtol=1e-5)      # float32 sums


def test_the_silhouettes_compiled_kernel_is_its_definition():
    """The silhouette's centre and moments (a compiled kernel) against the same definition
    written with OpenCV's operations, on lit and shaded balls with a contact shadow, noise,
    a second object touching the ball and balls cut by the patch's edge."""
    from tt_perception.detect import _silhouette_moments
    rng = np.random.default_rng(5)
    for trial in range(40):
        h, w = rng.integers(14, 30, size=2)
        background = rng.uniform(40, 120, size=(h, w, 3)).astype(np.float32)
        patch = background + rng.normal(0, 4, size=(h, w, 3))
        cx, cy = rng.uniform(-2, w + 2), rng.uniform(-2, h + 2)
        radius = rng.uniform(2.0, 6.0)
        yy, xx = np.mgrid[0:h, 0:w]
        inside = np.hypot(xx - cx, yy - cy) < radius
        lit = (yy - cy) < rng.uniform(-1, 2)
        patch[inside & lit] += rng.uniform(40, 120)
        patch[inside & ~lit] += rng.uniform(-10, 20)
        shadow = np.hypot(xx - cx - 1, yy - cy - radius) < radius
        patch[shadow & ~inside] -= 25.0                     # darker in all three: not ball
        if trial % 3 == 0:
            patch[:, int(w / 2):int(w / 2) + 1] += 60.0   # a line through the patch
        patch = np.clip(patch, 0, 255).astype(np.uint8)
        ys, xs = np.nonzero(inside & lit & (np.abs(patch - background).max(axis=2) > 22))
        if xs.size == 0:
            continue
        sx, sy = xs.min(), ys.min()
        seed = np.zeros((ys.max() - sy + 1, xs.max() - sx + 1), np.uint8)
        seed[ys - sy, xs - sx] = 1
        got = _silhouette_moments(patch, background, seed, sx, sy, 14.0)
        np.testing.assert_allclose(
            got, _silhouette_by_opencv(patch, background, seed, sx, sy, 14.0),
            rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize('later', [False, True])
@pytest.mark.parametrize('roi', [None, (300.0, 200.0)])
def test_background_follows_the_frame_except_around_the_ball(roi, later):
    """One update (background_every 1): the grey and the colour background move a
    background_rate of the way to the frame, except within 2 pixels (a 5 x 5 dilation) of the
    pixels whose grey differs by more than diff_threshold from the background times the
    light's gain (the ball; the frame is brighter by 6 levels), which keep their
    value; with a search window, as without. Left for later (as perception_node's camera
    threads do, once the detections are queued), the same update, when update_background
    is called: not before, not by a second search of the frame, and only once."""
    from scipy.ndimage import binary_dilation
    cfg = DetectorConfig(background_every=1, background_rate=0.25)
    rng = np.random.default_rng(4)
    first = rng.integers(70, 110, (240, 400, 3), dtype=np.uint8)
    first[:, :, 2] += 20                                   # colour: not a grey camera
    d = BallDetector(cfg)
    d.detect(first)
    grey0, colour0 = d.background.copy(), d._bg_colour.copy()
    frame = first + np.uint8(6)                            # light a little brighter
    disc(frame, (300.0, 200.0), 5.0)                       # and a ball
    found = d.detect(frame, roi, later=later)
    assert len(found) == 1
    gain = d.gain                    # the light's (light_gain): 101 / 95 on the table's median
    assert 1.04 < gain < 1.09
    if later:
        assert len(d.detect(frame, None, update_background=False)) == 1
        assert np.array_equal(d.background, grey0) and np.array_equal(d._bg_colour, colour0)
        d.update_background()
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY).astype(np.float32)
    ball = np.abs(grey - np.clip(np.round(grey0 * gain), 0, 255)) > cfg.diff_threshold
    assert 60 < ball.sum() < 120
    kept = binary_dilation(ball, np.ones((5, 5), bool))
    a = cfg.background_rate
    for _ in range(2):                     # a second call finds no update left to make
        assert np.allclose(d.background[kept], grey0[kept])
        assert np.allclose(d.background[~kept], ((1 - a) * grey0 + a * grey)[~kept], atol=1e-4)
        assert np.allclose(d._bg_colour[kept], colour0[kept])
        assert np.allclose(d._bg_colour[~kept], ((1 - a) * colour0 + a * frame)[~kept],
                           atol=1e-4)
        d.update_background()


def test_a_background_update_left_for_later_comes_before_the_next_frames_detection():
    """A caller that never calls update_background loses no update: the next frame's
    detection makes it first, so its detections and the backgrounds are those of a detector
    that updates at once (background_every 2: every other frame)."""
    cfg = DetectorConfig(background_every=2, background_rate=0.3)
    rng = np.random.default_rng(5)
    first = rng.integers(60, 100, (200, 300, 3), dtype=np.uint8)
    now, later = BallDetector(cfg), BallDetector(cfg)
    for d in (now, later):
        d.detect(first)
    for n in range(7):
        frame = first + np.uint8(2 * n)                    # the light changing
        disc(frame, (60.0 + 25.0 * n, 120.0 - 8.0 * n), 4.0)
        got_now = now.detect(frame)
        got_later = later.detect(frame, later=True)
        assert len(got_now) == 1 and got_later == got_now
    later.update_background()
    assert np.array_equal(later.background, now.background)
    assert np.array_equal(later._bg_colour, now._bg_colour)


@pytest.mark.parametrize('radius, blur', [(3.2, 0.0), (3.2, 0.35), (3.2, 0.8), (6.0, 0.6)])
def test_the_cameras_blur_is_estimated_from_the_outline_fits_of_its_balls(radius, blur):
    """:func:`estimate_image_blur` on 30 balls lit from above (:func:`top_lit_ball`: drawn and
    blurred by OpenCV, not by the fit's model) with 2 grey levels of noise, each fitted
    first with the perception_node default of 0.6 px as the detector fits them: the blur
    found is the one they were drawn with, within 0.1 px, though the grid it searches is
    0.1 px apart and the light falls on one side."""
    from tt_perception.detect import OutlineFit, estimate_image_blur
    size = int(2 * radius) + 14
    rng = np.random.default_rng(5)
    ball = BallImage(0.0, 0.0, np.eye(2) * radius, np.zeros(2))
    fits = []
    for _ in range(30):
        centre = 0.5 * size + rng.uniform(-1.0, 1.0, 2)
        grey, background = top_lit_ball(centre, radius, blur, size)
        grey += rng.normal(0.0, 2.0, grey.shape)
        fitter = OutlineFit(grey, background, np.ones((size, size), bool), ball,
                            image_blur=0.6)
        fits.append((fitter, fitter.fit(np.round(centre))[0]))
    found, n = estimate_image_blur(fits)
    assert n == 30
    assert abs(found - blur) < 0.1, found


def streaked_top_lit_fits(exposure, told, blur, told_blur, n=30, seed=7):
    """``n`` balls 3.2 px in radius lit from above, each streaked over ``exposure`` (s) along
    its own direction at 1.6 px per ms (the mean of :func:`top_lit_ball` at the middles of
    24 equal parts of its path: drawn by OpenCV, not by the fit's model), blurred by
    ``blur`` px, with 2 grey levels of noise, each fitted with the ``told`` exposure's
    streak and ``told_blur`` as the detector fits them: (OutlineFit, centre) pairs."""
    from tt_perception.detect import OutlineFit
    radius, speed = 3.2, 1.6e3                             # px, px/s
    rng = np.random.default_rng(seed)
    size = int(2 * radius + speed * max(exposure, told)) + 14
    fits = []
    for _ in range(n):
        centre = 0.5 * size + rng.uniform(-1.0, 1.0, 2)
        angle = rng.uniform(0.0, 2.0 * np.pi)
        way = speed * np.array([np.cos(angle), np.sin(angle)])
        path = centre + ((np.arange(24) + 0.5) / 24 - 0.5)[:, None] * way * exposure
        grey = np.mean([top_lit_ball(p, radius, blur, size, sub=4)[0] for p in path], axis=0)
        background = np.full((size, size), 200.0 * 0.15)
        grey += rng.normal(0.0, 2.0, grey.shape)
        ball = BallImage(0.0, 0.0, np.eye(2) * radius, way * told)
        fitter = OutlineFit(grey, background, np.ones((size, size), bool), ball,
                            image_blur=told_blur)
        fits.append((fitter, fitter.fit(np.round(centre))[0]))
    return fits


@pytest.mark.parametrize('exposure, told', [(5e-3, 2e-3), (2e-3, 5e-3), (1e-3, 2e-3)])
def test_the_exposure_is_estimated_from_the_streaks_of_the_balls(exposure, told):
    """:func:`estimate_exposure` on :func:`streaked_top_lit_fits` blurred by 0.5 px and
    fitted so: the exposure found is the one they were drawn with, within 0.1 ms (the grid
    tried is 0.33 ms apart; found 5.00, 2.01, 1.03 ms)."""
    from tt_perception.detect import estimate_exposure
    found, n = estimate_exposure(streaked_top_lit_fits(exposure, told, 0.5, 0.5), told,
                                 1.0 / 150.0)
    assert n == 30
    assert abs(found - exposure) < 0.1e-3, found


@pytest.mark.parametrize('exposure, blur', [(5e-3, 0.0), (1e-3, 1.0)])
def test_the_exposure_and_the_blur_are_estimated_together(exposure, blur):
    """:func:`estimate_exposure_and_blur` on :func:`streaked_top_lit_fits` fitted first as
    the detector's first pass fits them, at 2 ms and 0.6 px, which a sharp camera's ball
    streaked for 5 ms, or a blurred one for 1 ms, is not: both are found, the exposure
    within 0.15 ms and the blur within 0.15 px. (The exposure alone, at 0.6 px, is 0.3 ms
    short on the sharp camera.)"""
    from tt_perception.detect import estimate_exposure_and_blur
    fits = streaked_top_lit_fits(exposure, 2e-3, blur, 0.6, seed=11)
    found, found_blur, n = estimate_exposure_and_blur(fits, 2e-3, 1.0 / 150.0)
    assert n == 30
    assert abs(found - exposure) < 0.15e-3 and abs(found_blur - blur) < 0.15, (found,
                                                                               found_blur)


def test_no_fit_gives_no_blur_estimate():
    from tt_perception.detect import (
        OutlineFit,
        estimate_exposure,
        estimate_exposure_and_blur,
        estimate_image_blur,
    )
    empty = OutlineFit(np.zeros((9, 9)), np.zeros((9, 9)), np.zeros((9, 9), bool),
                       BallImage(0.0, 0.0, np.eye(2) * 3.0, np.zeros(2)))
    assert estimate_image_blur([]) == (None, 0)
    assert estimate_image_blur([(empty, (4.0, 4.0))]) == (None, 0)      # no pixel to fit
    assert estimate_exposure([(empty, (4.0, 4.0))], 2e-3, 1.0 / 150.0) == (None, 0)
    assert estimate_exposure_and_blur([(empty, (4.0, 4.0))], 2e-3, 1.0 / 150.0) == (None,
                                                                                   None, 0)


def lit_ball_with_highlight(centre, radius, blur, size, spot, sub=8):
    """:func:`top_lit_ball`'s ball (its linear shading, which the fit's quadratic follows
    exactly) with a Blinn-Phong highlight of 0.45 of full light and exponent 30 on the
    sphere, whose peak normal is ``spot`` rad from the camera toward the image's top (a light
    above a camera looking across): drawn here on ``sub`` x ``sub`` points per pixel, the
    sphere's normal from the image position. Returns (the patch, its background), float."""
    fine = (np.arange(size * sub) + 0.5) / sub - 0.5
    gy, gx = np.meshgrid(fine, fine, indexing='ij')
    dx, dy = (gx - centre[0]) / radius, (gy - centre[1]) / radius
    inside = dx * dx + dy * dy < 1.0
    toward_camera = np.sqrt(np.clip(1.0 - dx * dx - dy * dy, 0.0, 1.0))
    cosine = np.clip(-dy * np.sin(spot) + toward_camera * np.cos(spot), 0.0, 1.0)
    lit = np.where(inside, 0.6 - 0.4 * dy + 0.45 * cosine ** 30, 0.15)
    if blur > 0.0:
        lit = cv2.GaussianBlur(lit, (0, 0), blur * sub)
    grey = 200.0 * lit.reshape(size, sub, size, sub).mean(axis=(1, 3))
    return grey, np.full((size, size), 200.0 * 0.15)


def test_a_specular_highlight_moves_the_fitted_centre_less_with_the_inside_weighted():
    """A ball 6 px in radius lit from above with a specular highlight near its top
    (:func:`lit_ball_with_highlight`), blurred by 0.5 px, with 2 grey levels of noise, at 40
    sub-pixel positions. The highlight is a spot the quadratic shading cannot follow: fitted
    with every pixel alike (``inside_huber`` 0) the centre leans away from it, down, by over
    0.1 px on average (measured 0.125); with the pixels inside the ball weighted by how well
    the fit explains them (the default) the lean is under 0.6 of that (measured 0.069), and
    across the light (x) neither leans."""
    from tt_perception.detect import OutlineFit
    radius, blur, size = 6.0, 0.5, 32
    rng = np.random.default_rng(5)
    ball = BallImage(0.0, 0.0, np.eye(2) * radius, np.zeros(2))
    errors = {0.0: [], DetectorConfig().inside_huber: []}
    for _ in range(40):
        centre = 0.5 * size + rng.uniform(-1.0, 1.0, 2)
        grey, background = lit_ball_with_highlight(centre, radius, blur, size, spot=0.6)
        grey += rng.normal(0.0, 2.0, grey.shape)
        for huber in errors:
            fit = OutlineFit(grey, background, np.ones(grey.shape, bool), ball,
                             curvature_weight=DetectorConfig().curvature_weight,
                             image_blur=blur, inside_huber=huber).fit(np.round(centre))
            errors[huber].append(fit[0] - centre)
    plain, weighted = (np.mean(e, axis=0) for e in errors.values())
    assert plain[1] > 0.1, plain
    assert 0.0 < weighted[1] < 0.6 * plain[1], (weighted, plain)
    assert abs(plain[0]) < 0.02 and abs(weighted[0]) < 0.02


@pytest.mark.parametrize('background_light', [0.05, 0.15])
def test_a_blur_of_the_encoded_values_is_fitted_without_a_lean(background_light):
    """A camera that blurs its pixel values after its response (JPEG's smoothing after a
    gamma response) blurs the encoded values, not the light: undone to light, an edge's
    half-way level moves toward its bright side by more where its contrast ratio is larger,
    so the lit top's edge moves into the ball more than the shaded bottom's. A ball 3.2 px in
    radius lit from above (light 0.9 at its top falling linearly to 0.15 at its bottom, over
    a background of 0.05 or 0.15 of full scale), averaged over each pixel on 8 x 8 points,
    encoded with a 2.2 response, blurred on the pixel grid by SciPy's Gaussian filter of
    0.5 px and rounded to 8 bits, at 80 sub-pixel positions, linearised as the detector
    does: fitted as a blur of the light of the same 0.5 px the centre leans down, away from
    the lit top, by more than 0.05 px (mean); with the blur of the encoded values modelled
    (``encoded``, 0.5 px) within 0.025 px on each axis."""
    from scipy.ndimage import gaussian_filter
    from tt_perception.detect import OutlineFit
    radius, size, sub, gamma, blur = 3.2, 24, 8, 2.2, 0.5
    rng = np.random.default_rng(11)
    ball = BallImage(0.0, 0.0, np.eye(2) * radius, np.zeros(2))
    fine = (np.arange(size * sub) + 0.5) / sub - 0.5
    gy, gx = np.meshgrid(fine, fine, indexing='ij')
    background = np.full((size, size), 255.0 * background_light)
    usable = np.ones((size, size), bool)
    errors = {'light': [], 'encoded': []}
    for _ in range(80):
        centre = 12.0 + rng.uniform(-1.0, 1.0, 2)
        dy = (gy - centre[1]) / radius
        light = np.where(np.hypot(gx - centre[0], gy - centre[1]) < radius,
                         0.525 - 0.375 * dy, background_light)
        light = light.reshape(size, sub, size, sub).mean(axis=(1, 3))
        values = np.round(gaussian_filter(255.0 * light ** (1.0 / gamma), blur, mode='nearest'))
        seen = 255.0 * (values / 255.0) ** gamma
        for name, image_blur, encoded in (('light', blur, None),
                                          ('encoded', 0.0, (background, gamma, blur))):
            fit = OutlineFit(seen, background, usable, ball, curvature_weight=1.0,
                             image_blur=image_blur, encoded=encoded).fit((12.0, 12.0))
            errors[name].append(fit[0] - centre)
    assert np.mean(errors['light'], axis=0)[1] > 0.05, np.mean(errors['light'], axis=0)
    assert np.all(np.abs(np.mean(errors['encoded'], axis=0)) < 0.025), \
        np.mean(errors['encoded'], axis=0)


def spotted_table(seed=0):
    """A dark table (BACKGROUND) with 40 light grey spots of 2 px radius (a patterned floor,
    marks, a line's pieces): what a change of the light makes differ from the background."""
    rng = np.random.default_rng(seed)
    frame = np.full((120, 160, 3), BACKGROUND, np.uint8)
    for centre in rng.uniform((5.0, 5.0), (155.0, 115.0), (40, 2)):
        disc(frame, centre, 2.0, value=200)
    return frame


@pytest.mark.parametrize('gain', [0.85, 1.15])
def test_a_flickering_light_is_taken_out_of_the_background(gain):
    """Lamps on alternating current flicker at 100 or 120 Hz, and a 150 fps camera catches
    each frame at another phase: the whole frame, ball and table, is brighter or darker
    than the background learnt. The background times the light's gain is what the frame
    shows where no ball is: the 200-level spots, 30 levels off (over the 22 of
    ``diff_threshold``), are no candidates, and the ball's centre is found as under a
    steady light, by its blob and by its outline fit (told the outline's size; OpenCV's
    anti-aliased disc is not an exact one, so the fit is held to its own under the steady
    light, itself within 0.2 px)."""
    table = spotted_table()
    d = BallDetector(DetectorConfig(colour='white', image_blur=0.0))
    d.detect(table)
    centre = (81.3, 58.6)
    steady = disc(table.copy(), centre, 4.0)
    expected = BallImage(centre[0] + 0.3, centre[1] - 0.3, np.eye(2) * 4.0, (0.0, 0.0))
    fit_steady = d.detect(steady, roi_centre=centre, update_background=False, expected=expected)
    assert d.gain == 1.0      # under the steady light the background is used as it is
    assert len(fit_steady) == 1 and fit_steady[0].fitted
    assert np.hypot(fit_steady[0].u - centre[0], fit_steady[0].v - centre[1]) < 0.2
    lit = np.clip(steady.astype(float) * gain, 0, 255).round().astype(np.uint8)
    found = d.detect(lit, update_background=False)
    assert len(found) == 1 and abs(d.gain - gain) < 0.01
    assert np.hypot(found[0].u - centre[0], found[0].v - centre[1]) < 0.1
    fit = d.detect(lit, roi_centre=centre, update_background=False, expected=expected)
    assert len(fit) == 1 and fit[0].fitted
    assert np.hypot(fit[0].u - fit_steady[0].u, fit[0].v - fit_steady[0].v) < 0.05


def test_lamps_on_three_phases_are_taken_out_of_the_background_part_by_part():
    """Lamps on the three phases of the mains, each lighting a part of the hall, flicker out
    of step: across the frame the light is 1.2 times the background's at the edges and 0.8
    times in the middle, while the whole frame's median ratio stays 1. Each part's gain
    (light_gains) is taken out of the background: of the 200-level spots, up to 40 levels
    off, none is a candidate, and the ball is found where it is. A part half hidden by
    something moving (a person: levels at random) has no one ratio and keeps the frame's
    gain, and a steady light keeps the one gain."""
    rng = np.random.default_rng(3)
    table = np.full((480, 640, 3), BACKGROUND, np.uint8)
    for centre in rng.uniform((5.0, 5.0), (635.0, 475.0), (600, 2)):
        disc(table, centre, 2.0, value=200)
    d = BallDetector(DetectorConfig(colour='white', image_blur=0.0))
    d.detect(table)
    centre = (250.3, 300.6)
    light = 1.0 + 0.2 * np.cos(2.0 * np.pi * np.arange(640) / 640.0)[None, :, None]
    lit = np.clip(disc(table.copy(), centre, 4.0) * light, 0, 255).round().astype(np.uint8)
    found = d.detect(lit, update_background=False)
    assert d.gain == 1.0 and d.gain_grid is not None
    assert np.allclose(d.gain_grid, 1.0 + 0.2 * np.cos(
        2.0 * np.pi * (np.arange(6) + 0.5) / 6.0), atol=0.02)     # each part's, at its middle
    assert len(found) == 1
    assert np.hypot(found[0].u - centre[0], found[0].v - centre[1]) < 0.1
    moving = table.copy()
    moving[0:120, 0:107] = rng.integers(16, 250, (120, 107, 3))
    assert light_gains(moving, cv2.cvtColor(table, cv2.COLOR_BGR2GRAY)) == (1.0, None)
    steady = np.clip(table * 1.02, 0, 255).round().astype(np.uint8)
    assert light_gains(steady, cv2.cvtColor(table, cv2.COLOR_BGR2GRAY)) == (1.0, None)


@pytest.mark.parametrize('white', [90, 150, 200])
def test_the_exposure_level_is_the_brightness_of_the_whites_in_view(white):
    """A blue table with white lines 4 px wide at ``white`` grey levels: the camera's level
    is that over 180 (1 at most); the table alone, however dark, holds no white and says
    nothing of the exposure (1); a camera balanced for a warm light (its white_bgr) sees its
    warm white lines as white."""
    table = np.tile(np.array([95, 60, 25], np.uint8), (120, 160, 1))
    lined = table.copy()
    lined[40:44, :] = white
    lined[:, 70:74] = white
    grey = cv2.cvtColor(lined, cv2.COLOR_BGR2GRAY)
    assert exposure_level(grey, lined.astype(np.float32)) == pytest.approx(min(white / 180, 1))
    assert exposure_level(cv2.cvtColor(table, cv2.COLOR_BGR2GRAY),
                          table.astype(np.float32)) == 1.0
    warm = lined.astype(np.float32)
    warm[40:44, :] = warm[:, 70:74] = np.array([0.6, 0.85, 1.0]) * white
    assert exposure_level(grey, warm) == 1.0      # warm lines, the camera not told: no white
    assert exposure_level(grey, warm, (0.6, 0.85, 1.0)) == pytest.approx(min(white / 180, 1))
