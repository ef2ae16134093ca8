"""Ball detection in one camera's frames: motion against a background model, then colour and
size, with a sub-pixel centre.

A pixel is a candidate when its grey level differs from the running background by more than
``diff_threshold``, or its colour by more than ``colour_change_threshold`` in some channel
where hardly any grey change touches it (:func:`colour_only_blobs`: a ball as grey as what is
behind it); 8-connected candidate pixels form blobs. A blob is kept when its area lies
within [min_area, max_area] pixels, its mean colour matches the ball's (white: the three
channels close and bright; orange: red well above blue), and its width (twice the square root
of the smaller eigenvalue of its second moments, the diameter of a disc whatever the motion
blur along the path) is within range. Its first centre is the centroid of the ball's
silhouette (:meth:`BallDetector._silhouette_centre`), which for a motion-blurred disc is the
centre at mid-exposure. When the caller knows where the ball should be (the tracker's
prediction) only a region of interest around it is searched; a blob cut by the window's edge
is not measured (a ball merging with a larger object there would give a biased centre).

When the caller also knows how the ball should look (``expected``, a :class:`BallImage`: the
outline of the sphere at its predicted depth and its motion over the exposure), the centre is
a fit of that outline to the pixels (:func:`fit_outline`): the image is modelled as the
background mixed with the ball in proportion to the ball's coverage of each pixel, with the
ball's brightness a smooth field over its image, so a side of the ball as dark as the
background behind it carries no weight and the known size places the centre from the sides
that are seen, whatever the lighting.

The background follows slow changes of lighting (exponential average, ``background_rate`` per
update, one update every ``background_every`` frames) except under the blobs found, so a ball
that hovers does not fade into it; a frame brighter or darker as a whole (lamps flickering
with the mains, an automatic exposure) is compared with the background times its gain
(:func:`light_gain`), and the colours are judged as if the camera were exposed to show its
whites at :data:`WHITE_LEVEL` (:func:`exposure_level`).
"""

import collections
import dataclasses
import math

import cv2
from numba import njit
import numpy as np

EXPOSURE_RANGE = (1e-5, 0.1)
"""Accepted exposure times (:attr:`DetectorConfig.exposure`), s: perception_node's parameter,
tt-perceive's option."""
RESPONSE_GAMMA_RANGE = (1.0, 3.0)
"""Accepted camera responses (:attr:`DetectorConfig.response_gamma`), as EXPOSURE_RANGE."""
IMAGE_BLUR_RANGE = (0.0, 5.0)
"""Accepted camera blurs (:attr:`DetectorConfig.image_blur`), pixels, as EXPOSURE_RANGE."""
IMAGE_BLUR_GRID = tuple(round(0.1 * i, 1) for i in range(16))
"""Camera blurs tried by :func:`estimate_image_blur`, pixels: 0 to 1.5 in steps of 0.1."""
EXPOSURE_STEPS = 21
"""Exposures tried by :func:`estimate_exposure`: 0 to the frame period in 20 steps (0.33 ms
at 150 fps)."""


NEAREST_BALL_M = 0.739
"""The nearest a ball comes to a camera, m, for the pixel sizes :func:`sized_for` sets: a
ball 40 mm across 30 px wide through a 640 x 480 camera with a 60 degree lens (focal length
554 px; 1280 x 720: 60 px, 1920 x 1080: 90 px). With these sizes fixed in pixels, a 1920 x
1080 camera's ball was refused once nearer than 2.2 m: a hall scene's last 15 frames, the
ball coming to the robot (synth, 7 Dec 2026)."""
BALL_RADIUS_M = 0.02
"""A regulation ball's radius, m (ModelParams.radius), for the sizes of a detector not told
its ball's."""
REFERENCE_FOCAL_PX = 554.256
"""The focal length, pixels, of the camera a :class:`BallDetector` is sized for when it is
not told its own (synth.demo_rig at 640 x 480)."""


@dataclasses.dataclass
class DetectorConfig:
    """Thresholds of :class:`BallDetector` (pixels, grey levels)."""

    diff_threshold: float = 22.0
    """Minimum grey-level change against the background for a ball pixel."""
    colour_change_threshold: float = 44.0
    """Minimum change of one colour channel against the colour background, some channel not
    darker (a shadow darkens all three), for the pixels of a ball that fewer than ``min_area``
    pixels changed in grey by ``diff_threshold`` touch (:func:`colour_only_blobs`): a ball as
    grey as what is behind it."""
    min_area: int = 4
    """Smallest blob area, pixels."""
    max_area: int = 0
    """Largest blob area, pixels (a near, motion-blurred ball); 0: the largest width's square
    (:func:`sized_for`)."""
    max_width: float = 0.0
    """Largest blob width across its motion (ball diameter), pixels; 0: a ball at
    NEAREST_BALL_M from the camera (:func:`sized_for`)."""
    colour: str = 'any'
    """Ball colour: 'white', 'orange' or 'any'."""
    white_bgr: tuple = (1.0, 1.0, 1.0)
    """The colour (B, G, R) of a white surface in the camera's images, the largest 1 (the
    rig's ``white_bgr``): the ball's colour is divided by it before it is judged
    (:func:`colour_matches`), so that a white ball under a warm light is still white."""
    background_rate: float = 0.1
    """Weight of a new frame in the running background (per update)."""
    background_every: int = 3
    """Frames between two updates of the background."""
    roi_half_size: int = 0
    """Half size of the search window around a predicted position, pixels; 0: 4/3 of the
    largest width (:func:`sized_for`)."""
    max_candidates: int = 4
    """Most blobs returned per frame (the largest differences first)."""
    silhouette_threshold: float = 14.0
    """Smallest colour change (largest over B, G, R against the colour background) of a pixel
    of the ball's silhouette, grey levels: low enough to keep its shaded underside."""
    exposure: float = 2e-3
    """Exposure time of the camera, s: the ball's motion blur is its image velocity times it."""
    response_gamma: float = 1.0
    """The camera's response: a pixel value is 255 (L / L_max)^(1 / response_gamma) of the
    light L it got. 1: linear (synth's scenes, machine-vision cameras with gamma off); about
    2.2 for a camera that encodes like sRGB (most webcams). The outline fit mixes ball and
    background light in an outline pixel, so it undoes the response first."""
    curvature_weight: float = 1.0
    """Penalty of the outline fit on the curvature of the ball's brightness (the quadratic's
    part that a brightness linear over the image does not explain), in units of that
    curvature's own squared contribution to the ball's pixels (:func:`fit_outline`). On a
    ball a few pixels across, blurred by demosaicing and JPEG, a free curvature lets the
    fitted outline slide toward the lit side where the shaded side is invisible (a second
    minimum 0.4 radius up, docs/perception.md). 0: a free quadratic, the least biased under
    a single compact light with no ambient (a sharp terminator)."""
    light_from_above: bool = True
    """The hall's lights are above the table, so that the ball's top is brighter than its
    bottom. On a ball of 2-3 px radius whose shaded half is as dark as the background, the
    outline fit has two minima of nearly equal cost: the true centre with the lit top seen,
    and a centre up to a radius higher with the same pixels taken for a bottom lit from below
    (independent scenes, orange 640x480 at a track's start: 2.4 px up, 17 mm high after
    triangulation). With it, of the fits from several starts (:meth:`BallDetector.
    _fit_centre`) one lit from below (its brightness growing within 60 degrees of the
    image's down, :data:`LIT_FROM_BELOW_COS`) is kept only when every fit is so. False: any
    lighting."""
    image_blur: float = 0.6
    """The camera's own blur, pixels: the standard deviation of a Gaussian point spread (a
    Bayer camera's demosaicing, JPEG, the lens), modelled on the ball's outline and on its
    brightness by the fit. A blur spills more light past the outline on the ball's lit side
    than on its shaded one: on a ball 3-4 px in radius, modelled sharp, the fitted centre
    leans toward the lit top by 0.1-0.2 px. The default, 0.6 px, is the blur a Bayer colour
    camera's bilinear demosaicing gives its luma (the second moment of the interpolation
    kernels averaged over the mosaic's four sites and weighted as luma: sqrt(0.353)). JPEG
    q30 after a linear response counts as about 0.4 px; after a gamma response it leans the
    centre away from the lit side, which no value takes out ("A camera without a mosaic").
    0: a sharp camera (synth's clean mode; the ramp of one sub-sample).
    docs/perception_measured.md, "The camera's blur and the lit side". It costs no time (a
    fit samples each pixel once with it, four times without). :func:`estimate_image_blur`
    measures it from the fits (tt-perceive does by default). With a response
    (``response_gamma`` not 1) it is the blur of the light, before the response; the blur of
    the values after it is ``encoded_blur``."""
    encoded_blur: float = 0.5
    """The part of the camera's blur that acts on its pixel values after its response, pixels
    (the standard deviation of a Gaussian): JPEG's, which drops an edge's fine detail from the
    encoded values. Used only with a response (``response_gamma`` not 1): a blur of encoded
    values, undone to light, moves an edge's half-way level toward its bright side by more
    where its contrast ratio is larger, so the lit top's edge moves into the ball more than
    the shaded bottom's and a fit that blurs light reads the centre low (0.4-0.7 mm at
    640x480 through a camera without a mosaic, JPEG q30 after a 2.2 response). The fit
    models it (:class:`OutlineFit`, ``encoded``). 0.5 px: JPEG q30 on balls 2-7 px in radius
    (the independent renderer's, at which their heights are least biased: "JPEG's blur of
    the encoded values, modelled", docs/perception_measured.md); 0 for frames that were not
    compressed."""
    inside_huber: float = 2.0
    """Threshold of the Huber weights of the pixels the ball covers whole, in units of the
    fit's residual scale (:func:`inside_weights`): the fit is done again with the pixels its
    shading explains worst counting less. A specular highlight, a bright spot the quadratic
    shading cannot follow, otherwise bends the shading near the outline and moves the centre
    (synth's hall, orange ball at 1280x720: heights -0.39 mm, -0.24 with it; "A specular
    highlight", docs/perception_measured.md). 0: every pixel weighted alike (one fit less)."""


@dataclasses.dataclass
class Detection:
    """One ball candidate: sub-pixel centre (u, v) in the distorted image, pixels."""

    u: float
    v: float
    area: float
    width: float
    """Blob width across the motion blur (the ball's diameter), pixels."""
    strength: float
    """Mean grey-level difference against the background."""
    hidden: float = 0.0
    """Fraction of the blob's outline where the background is as bright as the ball (part
    of the ball may be missing from the blob there)."""
    fitted: bool = False
    """The centre is the fit of the expected outline (:func:`fit_outline`), not the
    silhouette's centroid."""
    blob_u: float = math.nan
    blob_v: float = math.nan
    """The blob's own centre (the silhouette's centroid), pixels: (u, v) unless ``fitted``."""
    colour_sure: bool = True
    """The blob's colour is the ball's. False: it only does not contradict it
    (:func:`colour_possible`: an orange ball a few pixels across whose colour JPEG's halved
    chroma resolution washed out); the pipeline uses such a candidate only together with a
    camera that is sure."""
    bright_width: float = math.nan
    """Width of the bright blob alone (its pixels' difference from the background above
    the detection threshold), pixels; ``width`` is the silhouette's, which takes in the
    shaded side too and, around a ball of a few pixels behind JPEG, the ringing of its
    compression block. The bright blob is not wider than the object."""
    bright_length: float = math.nan
    """The bright blob's length, the same measure as ``bright_width`` along its longest axis,
    pixels: a ball's is its width stretched by its motion over the exposure, a racket's
    disc seen at a slant is longer."""


@dataclasses.dataclass
class BallImage:
    """How the tracked ball should look in a frame, from its predicted state: where its centre
    projects, the outline of the sphere and its motion over the exposure (distorted pixels)."""

    u: float
    v: float
    """Projection of the ball's centre at the frame's time (the middle of the exposure)."""
    outline: np.ndarray
    """2 x 2 matrix M: the outline is the ellipse {c + M (cos a, sin a)} around the centre c."""
    blur: np.ndarray
    """(2,) the centre's displacement over the exposure, pixels."""
    up: np.ndarray = None
    """(2,) unit vector: the image of the world's up (+z) at the ball, or None when not
    known. Under overhead light the ball's top is its lit side (:attr:`DetectorConfig.
    light_from_above`)."""


WHITE_BALANCE = 0.72
"""Least ratio of a white ball's weakest colour channel to its strongest."""
LIT_MIN = 90.0
"""Least value of a ball's strongest channel in its lit half (the red of an orange ball)."""
ORANGE_RED_PER_BLUE = 1.6
ORANGE_RED_OVER_BLUE = 20.0
"""An orange ball's lit half has red above ORANGE_RED_PER_BLUE times its blue plus
ORANGE_RED_OVER_BLUE (and above its green)."""
WHITE_LEVEL = 180.0
"""Grey level of the brightest white in a camera's background (the table's white lines, the
net's tape: :func:`exposure_level`) at and above which the colour thresholds above hold as
they are (synth's scenes and the independent renderer's are brighter). A camera exposed
darker has its blobs' colours judged as if scaled up to it (:attr:`BallDetector.level`)."""
LEVEL_RANGE = (0.2, 1.0)
"""The range of :attr:`BallDetector.level`."""
LEVEL_COUNT = 20
"""The white pixels :func:`exposure_level` reads brighter than the level it gives."""
LEVEL_EVERY = 50
"""Background updates between two measures of :attr:`BallDetector.level` (a second at 150
fps: a camera's automatic exposure is followed)."""
WHITE_MIXED_BACKGROUND = 0.5
"""Largest share of the background in the mean colour of a white ball's lit half that
:func:`colour_matches` takes out: a ball blurred along its path over the exposure, or a few
pixels across, covers its pixels only in part, and the table shows through."""
ORANGE_MIXED_BACKGROUND = 0.5
"""The same for an orange ball (:func:`colour_possible`): a ball so mixed with the
background is possible, not sure (:attr:`Detection.colour_sure`)."""


def colour_matches(bgr, colour, change=None):
    """True when the mean colour ``bgr`` (3,) is that of a ``colour`` ball ('white', 'orange',
    'any'). ``change`` (3,), the colour minus the background's there, when known: an orange
    ball small enough for JPEG's halved chroma resolution to mix the background into it is
    still recognised by the red it adds over the blue; a white ball whose pixels mix in up
    to :data:`WHITE_MIXED_BACKGROUND` of the background (:func:`_white_mixed`) is white."""
    b, g, r = (float(c) for c in bgr)
    if colour == 'white':
        if max(b, g, r) <= LIT_MIN:
            return False
        if min(b, g, r) > WHITE_BALANCE * max(b, g, r):
            return True
        return change is not None and _white_mixed(bgr, np.subtract(bgr, change))
    if colour == 'orange':
        if r > LIT_MIN and r > ORANGE_RED_PER_BLUE * b + ORANGE_RED_OVER_BLUE and r > g:
            return True
        if change is None:
            return False
        db, dg, dr = (float(c) for c in change)
        return dr > 30.0 and dr > 1.6 * max(db, 0.0) + 10.0 and dr > dg
    return True


def _mixed_share(conditions, most):
    """Whether some share s, 0 < s <= ``most``, meets every condition c0 - s c1 > 0 of
    ``conditions`` [(c0, c1), ...]: each is linear in s, so the shares that meet them all are
    an interval, found exactly."""
    lo, hi = 0.0, most
    for c0, c1 in conditions:
        if c1 > 0.0:
            hi = min(hi, c0 / c1)
        elif c1 < 0.0:
            lo = max(lo, c0 / c1)
        elif c0 <= 0.0:
            return False
    return lo < hi


def _white_mixed(bgr, background):
    """Whether some share s of ``background`` (B, G, R), 0 < s <= WHITE_MIXED_BACKGROUND,
    taken out of the colour ``bgr`` (a pixel I = (1 - s) W + s G) leaves a white W: every
    channel i, j has (I_i - s G_i) > WHITE_BALANCE (I_j - s G_j). (A blue table mixed into a
    white ball's 5 ms blur: 180, 158, 128 against 90, 56, 23 is white once 0.1 of the table
    is taken out.)"""
    return _mixed_share([(float(bgr[i]) - WHITE_BALANCE * float(bgr[j]),
                          float(background[i]) - WHITE_BALANCE * float(background[j]))
                         for i in range(3) for j in range(3) if i != j],
                        WHITE_MIXED_BACKGROUND)


def _orange_mixed(bgr, background):
    """Whether some share s of ``background`` (B, G, R), 0 < s <= ORANGE_MIXED_BACKGROUND,
    taken out of the colour ``bgr`` (I = (1 - s) O + s G) leaves an orange O, one that
    :func:`colour_matches` takes without a background (each of its three conditions, times
    1 - s, is linear in s), every channel above 0. An orange ball in front of a white
    line, its shaded half and outline mixed with the line: 112, 127, 146 against 190, 177,
    164 is 34, 77, 128 with half the line taken out."""
    (b, g, r), (gb, gg, gr) = ((float(c) for c in bgr), (float(c) for c in background))
    k, c = ORANGE_RED_PER_BLUE, ORANGE_RED_OVER_BLUE
    return _mixed_share([(r - LIT_MIN, gr - LIT_MIN), (r - k * b - c, gr - k * gb - c),
                         (r - g, gr - gg), (b, gb), (g, gg)], ORANGE_MIXED_BACKGROUND)


def colour_possible(bgr, colour, change):
    """True when a blob whose mean colour ``bgr`` is not the ``colour`` ball's
    (:func:`colour_matches`, same arguments) may still be that ball: for an orange ball, a
    ``change`` against the background (B, G, R; None where no background is known) that
    adds red at least as much as blue or green, less 10 grey levels (a ball of 2-3 px radius
    behind JPEG 4:2:0 is grey, e.g. +43, +46, +54), or a colour that is orange once up to
    half the background is taken out of it (:func:`_orange_mixed`: a ball in front of
    something brighter, a white line, darkens every channel). Never for a white ball."""
    if colour != 'orange' or change is None:
        return False
    db, dg, dr = (float(c) for c in change)
    if dr > 0.0 and dr >= max(db, dg) - 10.0:
        return True
    return _orange_mixed(bgr, np.subtract(bgr, change))


def exposure_level(grey, colour=None, white_bgr=(1.0, 1.0, 1.0)):
    """How brightly a camera is exposed, from its background: the grey level (``grey``,
    uint8) of the brightest white in it over :data:`WHITE_LEVEL`, within
    :data:`LEVEL_RANGE`; 1 when it holds too little white to tell. The white: pixels (every
    second of both axes) whose ``colour`` (B, G, R, divided by the camera's ``white_bgr``;
    None for a grey camera: every pixel) has its weakest channel :data:`WHITE_BALANCE` of its
    strongest or more; its brightest: the :data:`LEVEL_COUNT`-th brightest of them.

    A white ball's lit half is about as bright as the scene's white lines; at 150 fps a
    hall's light can leave both at a third of the scale, under the colour thresholds'
    :data:`LIT_MIN` (synth's hall, its frames times 0.35: no state). Only white counts: a
    dark blue table is no sign of a dark exposure, and an orange ball streaked over it mixes
    to a dim grey that LIT_MIN alone tells from a white ball."""
    if colour is None:
        sample = grey[::2, ::2].ravel()
    else:
        sample = _white_levels(grey, colour, np.asarray(white_bgr, np.float64), WHITE_BALANCE)
    if sample.size < 2 * LEVEL_COUNT:
        return 1.0
    brightest = float(np.partition(sample, sample.size - LEVEL_COUNT)[sample.size - LEVEL_COUNT])
    return min(max(brightest / WHITE_LEVEL, LEVEL_RANGE[0]), LEVEL_RANGE[1])


@njit(cache=True, nogil=True)
def _white_levels(grey, colour, white_bgr, balance):
    """Kernel of :func:`exposure_level`: the grey levels of every second pixel of both axes
    whose colour (float32, divided by ``white_bgr``) has its weakest channel ``balance`` of
    its strongest or more."""
    h, w = grey.shape
    out = np.empty((h // 2 + 1) * (w // 2 + 1), np.uint8)
    n = 0
    for y in range(0, h, 2):
        for x in range(0, w, 2):
            b = colour[y, x, 0] / white_bgr[0]
            g = colour[y, x, 1] / white_bgr[1]
            r = colour[y, x, 2] / white_bgr[2]
            if min(b, g, r) >= balance * max(b, g, r):
                out[n] = grey[y, x]
                n += 1
    return out[:n]


def _width_from_moments(cxx, cyy, cxy, longest=False):
    """Width across the motion blur (the ball's diameter), pixels, from the central second
    moments of a blob's pixels (each pixel adds 1/12 of its own): a disc of radius r has
    variance r^2 / 4 along any axis, and blur only lengthens the other axis. ``longest``:
    the same measure along that other axis (a disc's diameter; a ball blurred by b px,
    sqrt(4 r^2 + 4 b^2 / 3))."""
    spread = np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy ** 2)
    axis = 0.5 * (cxx + cyy) + (spread if longest else -spread)
    return 4.0 * np.sqrt(max(axis, 0.0) + 1.0 / 12.0)


SUBPIXELS = 2
"""The model's samples per pixel along each axis (their coverage ramps are 1 / SUBPIXELS px)."""
BLUR_STEP = 0.5
"""Largest distance between two of the model's positions of the ball over the exposure, px."""
N_SHADING = 6
"""Terms of the model of the ball's brightness over its image (a quadratic)."""
CONVERGED = 0.03
"""A Gauss-Newton step of the centre shorter than this ends the fit, pixels."""
LIT_FROM_BELOW_COS = 0.5
"""A fitted ball is lit from below when its brightness gradient points within 60 degrees of
the image's down (the cosine of its angle to the world's up below -0.5) and changes its
brightness from the centre to the outline by more than :data:`SHADING_MIN` of the centre's."""
SHADING_MIN = 0.1
"""Below this change of brightness over the ball, in parts of its centre's, a fit's shading
has no direction that counts (a ball lit evenly)."""
SEARCH_STEP = 0.5
"""Distance of the extra starts of a fit with a rough prediction from the blob's centre,
in ball radii (:meth:`BallDetector._fit_centre`)."""
SEARCH_OFFSETS = ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))
"""Directions of those starts: along the image axes."""


@njit(cache=True, nogil=True)
def _blurred_shading(p, wx, wy, a, b, nx, ny, g, z, psf, slope, basis, dbasis):
    """Adds to pixel p's ``basis`` and ``dbasis`` (:func:`_render`) what the Gaussian blur of
    spread ``psf`` (px) makes of the ball's shading at an outline sample: at signed distance
    z psf from the outline along its outward normal (nx, ny), where the blurred coverage is
    Phi(-z) with slope ``slope``, whitened offset (wx, wy) from the centre (unclamped), and
    ``g`` = |A^T w|, the outline's normal before its normalisation; ``b`` = A^T A
    (b00, b01, b11).

    For a coverage c and a quadratic brightness s (gradient, Hessian in pixels), the blurred
    product is G * (c s) = (G * c) s + psf^2 grad s . grad (G * c) + psf^2 tr(H) (G * c) / 2 +
    psf^4 sum_kl H_kl d_k d_l (G * c) / 2 (the moments of the Gaussian); with G * c =
    Phi(-z) across a straight outline the second and fourth terms are added here (the third is
    a multiple of the coverage, which the constant term of the shading takes). Without them a
    shaded ball's blurred brighter side spills more light outside the outline than the
    product says, and the fitted centre leans toward it. The derivatives with respect to the
    centre are minus those with respect to the pixel (the distance's gradient taken as the
    normal)."""
    var = psf * psf
    pn = z * psf
    # The gradient (pixels) of the terms t = (1, wx, wy, wx^2, wx wy, wy^2), w = A d: A^T dt/dw.
    an0 = a[0, 0] * nx + a[0, 1] * ny           # A n: the normal's step in w per pixel
    an1 = a[1, 0] * nx + a[1, 1] * ny
    # The normal's change per pixel: (I - n n^T) B / g, B = A^T A.
    b00, b01, b11 = b
    for j in range(1, N_SHADING):
        if j == 1:
            gw0, gw1, hw0, hw1, nhn = 1.0, 0.0, 0.0, 0.0, 0.0
        elif j == 2:
            gw0, gw1, hw0, hw1, nhn = 0.0, 1.0, 0.0, 0.0, 0.0
        elif j == 3:
            gw0, gw1, hw0, hw1, nhn = 2.0 * wx, 0.0, 2.0 * an0, 0.0, 2.0 * an0 * an0
        elif j == 4:
            gw0, gw1, hw0, hw1, nhn = wy, wx, an1, an0, 2.0 * an0 * an1
        else:
            gw0, gw1, hw0, hw1, nhn = 0.0, 2.0 * wy, 0.0, 2.0 * an1, 2.0 * an1 * an1
        # grad t = A^T dt/dw, grad t . n; H n = A^T (H_w A n).
        tx = a[0, 0] * gw0 + a[1, 0] * gw1
        ty = a[0, 1] * gw0 + a[1, 1] * gw1
        tn = tx * nx + ty * ny
        hnx = a[0, 0] * hw0 + a[1, 0] * hw1
        hny = a[0, 1] * hw0 + a[1, 1] * hw1
        basis[p, j] += -var * slope * tn + 0.5 * var * nhn * pn * slope
        # d/d pixel, with d slope = -slope pn / psf^2 n, d pn = n and d n = (I - n n^T) B / g:
        # d tn = H n + B (grad t - tn n) / g, d nHn = 2 B (H n - nHn n) / g.
        along = tn * pn * slope + 0.5 * var * nhn * slope * (1.0 - z * z)
        ex, ey = tx - tn * nx, ty - tn * ny
        dtn_x = hnx + (b00 * ex + b01 * ey) / g
        dtn_y = hny + (b01 * ex + b11 * ey) / g
        fx, fy = hnx - nhn * nx, hny - nhn * ny
        dnhn_x = 2.0 * (b00 * fx + b01 * fy) / g
        dnhn_y = 2.0 * (b01 * fx + b11 * fy) / g
        dbasis[p, 0, j] -= along * nx + var * slope * (0.5 * pn * dnhn_x - dtn_x)
        dbasis[p, 1, j] -= along * ny + var * slope * (0.5 * pn * dnhn_y - dtn_y)


@njit(cache=True, nogil=True)
def _render(xs, ys, cx, cy, a, bu, bv, steps, sub, psf, cover, dcover, basis, dbasis):
    """Kernel of :func:`ball_model`: fills ``cover`` (P,), ``basis`` (P, N_SHADING) and their
    derivatives with respect to the centre, ``dcover`` (P, 2) and ``dbasis`` (P, 2, N_SHADING)."""
    inv = 1.0 / (steps * sub * sub)
    mean_radius = 1.0 / np.sqrt(a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0])
    t = np.empty(N_SHADING)
    dt = np.empty((N_SHADING, 2))
    # A Gaussian blur moves a curved outline's half-way level inward by psf^2 / 2 times its
    # curvature (the heat equation's curvature flow), taken as the mean radius's.
    shrink = 0.5 * psf * psf / mean_radius
    b = (a[0, 0] * a[0, 0] + a[1, 0] * a[1, 0], a[0, 0] * a[0, 1] + a[1, 0] * a[1, 1],
         a[0, 1] * a[0, 1] + a[1, 1] * a[1, 1])            # A^T A, for _blurred_shading
    for p in range(xs.size):
        cover[p] = 0.0
        dcover[p, 0] = dcover[p, 1] = 0.0
        for j in range(N_SHADING):
            basis[p, j] = dbasis[p, 0, j] = dbasis[p, 1, j] = 0.0
        # Samples inside the outline, fully covered: only their w and w w^T are summed here,
        # and their share of the basis and its derivative added after the pixel's loop.
        full = sum_x = sum_y = sum_xx = sum_xy = sum_yy = 0.0
        for k in range(steps):
            s = (k + 0.5) / steps - 0.5
            for iy in range(sub):
                dy = ys[p] + (iy + 0.5) / sub - 0.5 - cy - s * bv
                for ix in range(sub):
                    dx = xs[p] + (ix + 0.5) / sub - 0.5 - cx - s * bu
                    wx = a[0, 0] * dx + a[0, 1] * dy        # whitened: |w| = 1 on the outline
                    wy = a[1, 0] * dx + a[1, 1] * dy
                    norm = np.sqrt(wx * wx + wy * wy)
                    gx = a[0, 0] * wx + a[1, 0] * wy        # A^T w: the outline's normal
                    gy = a[0, 1] * wx + a[1, 1] * wy
                    g = np.sqrt(gx * gx + gy * gy)
                    along = norm / g if g > 1e-9 else mean_radius
                    edge = False
                    if psf > 0.0:
                        z = ((norm - 1.0) * along + shrink) / psf
                        if z >= 3.0:
                            continue
                        if z > -3.0 and g > 1e-9:
                            c = 0.5 * math.erfc(z * 0.7071067811865476)
                            slope = math.exp(-0.5 * z * z) * 0.3989422804014327 / psf
                            dcx, dcy = slope * gx / g, slope * gy / g
                            edge = True
                        else:
                            c, dcx, dcy = 1.0, 0.0, 0.0
                    else:
                        c = 0.5 - (norm - 1.0) * along * sub
                        if c <= 0.0:
                            continue
                        # d c / d centre: the outline's unit normal, times the ramp's slope.
                        if c < 1.0 and g > 1e-9:
                            dcx, dcy = sub * gx / g, sub * gy / g
                        else:
                            c, dcx, dcy = min(c, 1.0), 0.0, 0.0
                    if c == 1.0 and dcx == 0.0 and dcy == 0.0 and norm <= 1.0:
                        full += 1.0
                        sum_x += wx
                        sum_y += wy
                        sum_xx += wx * wx
                        sum_xy += wx * wy
                        sum_yy += wy * wy
                        continue
                    # d w / d centre = -A; an outline sample takes the limb's w / |w| (with
                    # the blur the quadratic runs on past the limb: _blurred_shading).
                    d00, d01, d10, d11 = -a[0, 0], -a[0, 1], -a[1, 0], -a[1, 1]
                    if norm > 1.0 and psf == 0.0:
                        wx /= norm
                        wy /= norm
                        # d (w / |w|) = (I - u u^T) dw / |w|
                        e00, e01 = (1.0 - wx * wx) / norm, -wx * wy / norm
                        e11 = (1.0 - wy * wy) / norm
                        d00, d01, d10, d11 = (e00 * d00 + e01 * d10, e00 * d01 + e01 * d11,
                                              e01 * d00 + e11 * d10, e01 * d01 + e11 * d11)
                    t[0], t[1], t[2] = 1.0, wx, wy
                    t[3], t[4], t[5] = wx * wx, wx * wy, wy * wy
                    for m in range(2):
                        dwx = d00 if m == 0 else d01
                        dwy = d10 if m == 0 else d11
                        dt[0, m] = 0.0
                        dt[1, m] = dwx
                        dt[2, m] = dwy
                        dt[3, m] = 2.0 * wx * dwx
                        dt[4, m] = dwx * wy + wx * dwy
                        dt[5, m] = 2.0 * wy * dwy
                    cover[p] += c
                    dcover[p, 0] += dcx
                    dcover[p, 1] += dcy
                    for j in range(N_SHADING):
                        basis[p, j] += c * t[j]
                        dbasis[p, 0, j] += dcx * t[j] + c * dt[j, 0]
                        dbasis[p, 1, j] += dcy * t[j] + c * dt[j, 1]
                    if edge:
                        _blurred_shading(p, wx, wy, a, b, gx / g, gy / g, g, z, psf, slope,
                                         basis, dbasis)
        if full > 0.0:
            # t = (1, wx, wy, wx^2, wx wy, wy^2) and, with d w / d centre = -A inside,
            # d t / d centre_m = (0, dwx, dwy, 2 wx dwx, dwx wy + wx dwy, 2 wy dwy).
            cover[p] += full
            basis[p, 0] += full
            basis[p, 1] += sum_x
            basis[p, 2] += sum_y
            basis[p, 3] += sum_xx
            basis[p, 4] += sum_xy
            basis[p, 5] += sum_yy
            for m in range(2):
                dwx, dwy = -a[0, m], -a[1, m]
                dbasis[p, m, 1] += full * dwx
                dbasis[p, m, 2] += full * dwy
                dbasis[p, m, 3] += 2.0 * dwx * sum_x
                dbasis[p, m, 4] += dwx * sum_y + dwy * sum_x
                dbasis[p, m, 5] += 2.0 * dwy * sum_y
        cover[p] *= inv
        dcover[p, 0] *= inv
        dcover[p, 1] *= inv
        for j in range(N_SHADING):
            basis[p, j] *= inv
            dbasis[p, 0, j] *= inv
            dbasis[p, 1, j] *= inv


def _whiten(outline):
    """A = (M M^T)^(-1/2) of an outline M: |A d| = 1 on the outline, d from the centre.

    Written out for 2 x 2: with S = M M^T, s = sqrt(det S) and q = sqrt(tr S + 2 s),
    S^(1/2) = (S + s I) / q, so S^(-1/2) = ((tr S + s) I - S) / (s q). All nan for an
    outline of no area (or not finite)."""
    m = outline @ outline.T
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    if not (det > 0.0 and math.isfinite(det)):
        return np.full((2, 2), np.nan)
    s = math.sqrt(det)
    trace = m[0, 0] + m[1, 1]
    return ((trace + s) * np.eye(2) - m) / (s * math.sqrt(trace + 2.0 * s))


def _outline_extent(outline):
    """The largest and the geometric mean of the semi-axes of an outline M (its singular
    values' largest and sqrt |det M|), pixels."""
    m = outline @ outline.T
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    half_trace = 0.5 * (m[0, 0] + m[1, 1])
    largest = math.sqrt(half_trace + math.sqrt(max(half_trace * half_trace - det, 0.0)))
    return largest, math.sqrt(math.sqrt(max(det, 0.0)))


def _sampling(ball, image_blur):
    """How :func:`ball_model` samples ``ball``: (positions over the exposure, sub-samples per
    pixel along each axis, Gaussian spread of the outline in pixels or 0 for the ramps)."""
    if image_blur > 0.0:
        # One sample per pixel, at its centre: a Gaussian edge averaged over the pixel's
        # width is close to a Gaussian of the variances' sum (the box's: 1/12 px^2). Copies
        # of a Gaussian 1.5 spreads apart sum to a flat band within 3e-4 of its height (the
        # ripple's first harmonic, 2 exp(-2 pi^2 / 1.5^2)): positions need not be 0.5 px
        # apart (a 3.2 px ball moving 4.7 px: coverage within 0.005 of theirs, half the time).
        spread = math.sqrt(image_blur ** 2 + 1.0 / 12.0)
        spacing, sub = max(BLUR_STEP, 1.5 * spread), 1
    else:
        spread, spacing, sub = 0.0, BLUR_STEP, SUBPIXELS
    return max(1, int(np.ceil(np.hypot(ball.blur[0], ball.blur[1]) / spacing))), sub, spread


def ball_model(xs, ys, centre, ball, whitening=None, image_blur=0.0):
    """The image of the ball ``ball`` (:class:`BallImage`) with its centre at ``centre`` at
    mid-exposure, at the pixels (xs, ys) (1-D float arrays of pixel centres): its mean
    coverage of each pixel over the exposure (P,) and the basis (P, 6) of its brightness,
    such that a pixel is I = G (1 - coverage) + basis @ shading for a background G; and their
    derivatives with respect to the centre's u and v, (P, 2) and (P, 2, 6).

    The ball is the outline ``ball.outline`` moving by ``ball.blur`` over the exposure
    (positions at most :data:`BLUR_STEP` apart); each pixel is sampled at SUBPIXELS^2 points,
    each covered by clip(0.5 - SUBPIXELS s) of its signed distance s to the outline. The
    ball's brightness is a quadratic over its image (in offsets from the centre scaled to
    the outline; an outline sample takes the outline's brightness), whatever the light.
    ``whitening``: :func:`_whiten` of the outline, when computed already. ``image_blur`` >
    0: the camera's own blur (demosaicing, compression, lens), a Gaussian of that standard
    deviation in pixels: each pixel is sampled once, at its centre, covered by
    Phi(-s / sqrt(image_blur^2 + 1/12)) of its signed distance s (the camera's blur and the
    pixel's width; s taken in by the blurred outline's curvature shrink) instead of the
    ramps, and the brightness blurred with the coverage (:func:`_blurred_shading`)."""
    n = xs.size
    cover, dcover = np.empty(n), np.empty((n, 2))
    basis, dbasis = np.empty((n, N_SHADING)), np.empty((n, 2, N_SHADING))
    if whitening is None:
        whitening = _whiten(ball.outline)
    steps, sub, spread = _sampling(ball, image_blur)
    _render(xs, ys, float(centre[0]), float(centre[1]), whitening,
            float(ball.blur[0]), float(ball.blur[1]), steps, sub, spread, cover, dcover, basis,
            dbasis)
    return cover, basis, dcover, dbasis


@njit(cache=True, nogil=True)
def _gram(a, b):
    """a^T b of two (P, n) and (P, m) arrays."""
    out = np.zeros((a.shape[1], b.shape[1]))
    for p in range(a.shape[0]):
        for i in range(a.shape[1]):
            for j in range(b.shape[1]):
                out[i, j] += a[p, i] * b[p, j]
    return out


@njit(cache=True, nogil=True)
def _gram_vector(a, b):
    """a^T b of a (P, n) array and a (P,) vector."""
    out = np.zeros(a.shape[1])
    for p in range(a.shape[0]):
        for i in range(a.shape[1]):
            out[i] += a[p, i] * b[p]
    return out


@njit(cache=True, nogil=True)
def curvature_penalty(basis, weight):
    """(N_SHADING, N_SHADING) matrix W of the penalty s^T W s on the shading s of
    :func:`ball_model`'s ``basis`` (P, N_SHADING, float): ``weight`` times the squared norm
    over the P pixels of the quadratic terms' image once its best linear fit (the first
    three terms) is taken out. Zero on the linear terms; independent of the brightness's
    units and of the number of pixels."""
    # The quadratic terms' least-squares fit by the linear ones (normal equations; a ridge of
    # 1e-12 of their scale where the linear terms are degenerate).
    linear, quadratic = basis[:, :3], basis[:, 3:]
    normal = _gram(linear, linear)
    scale = 1e-12 * (normal[0, 0] + normal[1, 1] + normal[2, 2]) + 1e-300
    for i in range(3):
        normal[i, i] += scale
    cross = _gram(linear, quadratic)
    coef = np.empty((3, 3))
    for j in range(3):
        coef[:, j] = _solve(normal, cross[:, j].copy())[0]
    beyond = np.empty((basis.shape[0], 3))
    for p in range(basis.shape[0]):
        for j in range(3):
            beyond[p, j] = (quadratic[p, j] - linear[p, 0] * coef[0, j]
                            - linear[p, 1] * coef[1, j] - linear[p, 2] * coef[2, j])
    out = np.zeros((N_SHADING, N_SHADING))
    product = _gram(beyond, beyond)
    for i in range(3):
        for j in range(3):
            out[3 + i, 3 + j] = weight * product[i, j]
    return out


@njit(cache=True, nogil=True)
def _solve(m, b):
    """x with m x = b (small, square; Gaussian elimination with partial pivoting), and False
    when m is singular to working precision (a pivot within n eps of m's largest entry), in
    which case x is undefined."""
    n = b.size
    a = m.copy()
    x = b.copy()
    tolerance = n * 2.220446049250313e-16 * np.abs(a).max()
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if not abs(a[pivot, col]) > tolerance:
            return x, False
        if pivot != col:
            for j in range(n):
                a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
            x[col], x[pivot] = x[pivot], x[col]
        for row in range(col + 1, n):
            f = a[row, col] / a[col, col]
            if f != 0.0:
                for j in range(col, n):
                    a[row, j] -= f * a[col, j]
                x[row] -= f * x[col]
    for col in range(n - 1, -1, -1):
        acc = x[col]
        for j in range(col + 1, n):
            acc -= a[col, j] * x[j]
        x[col] = acc / a[col, col]
    return x, True


@njit(cache=True, nogil=True)
def _residuals(obs, bg, cover, basis, shading, res):
    """Fills ``res`` with each pixel's observed minus modelled value,
    I - G (1 - c) - basis @ shading (:func:`ball_model`)."""
    for p in range(obs.size):
        r = obs[p] - bg[p] * (1.0 - cover[p])
        for j in range(N_SHADING):
            r -= basis[p, j] * shading[j]
        res[p] = r


@njit(cache=True, nogil=True)
def _not_posed(cx, cy, n):
    """:func:`_fit`'s answer when the fit is not posed, at the centre it had reached."""
    return False, cx, cy, 0.0, np.zeros(N_SHADING), np.zeros(n), np.zeros(n)


@njit(cache=True, nogil=True)
def _fit(obs, bg, xs, ys, cx, cy, a, bu, bv, steps, sub, psf, curvature_weight, iterations,
         converged, weight):
    """Kernel of :func:`fit_outline` on its usable pixels (obs, bg, xs, ys): (ok, u, v, cost,
    shading, residuals, cover), shading the N_SHADING terms of the ball's brightness,
    residuals and cover each pixel's observed minus modelled value and coverage by the ball
    at the end. ``weight``: the square root of each pixel's weight in the sum of squares
    (:func:`inside_weights`; ones: every pixel alike), ``cost`` the weighted sum. Not ok
    when a system is singular or the ball covers fewer pixels than there are unknowns (the
    shading's N_SHADING and the centre's 2): the fit is not posed."""
    n = xs.size
    k = N_SHADING + 2
    cover, dcover = np.empty(n), np.empty((n, 2))
    basis, dbasis = np.empty((n, N_SHADING)), np.empty((n, 2, N_SHADING))
    _render(xs, ys, cx, cy, a, bu, bv, steps, sub, psf, cover, dcover, basis, dbasis)
    if np.count_nonzero(cover) < k:
        return _not_posed(cx, cy, n)
    penalty = np.zeros((k, k))
    if curvature_weight > 0.0:
        penalty[:N_SHADING, :N_SHADING] = curvature_penalty(basis, curvature_weight)
    ridge = np.ascontiguousarray(penalty[:N_SHADING, :N_SHADING])
    weighted = basis * weight.reshape(n, 1)
    shading, ok = _solve(_gram(weighted, weighted) + ridge,
                         _gram_vector(weighted, (obs - bg * (1.0 - cover)) * weight))
    if not ok:          # the shading is not determined by these pixels
        return _not_posed(cx, cy, n)
    jac = np.empty((n, k))
    res = np.empty(n)
    for _ in range(iterations):
        # Gauss-Newton on the shading and the centre together: I = G (1 - c) + basis @ shading,
        # minimising |weight res|^2 + shading^T W shading.
        _residuals(obs, bg, cover, basis, shading, res)
        for p in range(n):
            res[p] *= weight[p]
            for j in range(N_SHADING):
                jac[p, j] = basis[p, j] * weight[p]
            for m in range(2):
                d = -bg[p] * dcover[p, m]
                for j in range(N_SHADING):
                    d += dbasis[p, m, j] * shading[j]
                jac[p, N_SHADING + m] = d * weight[p]
        gradient = _gram_vector(jac, res)
        gradient[:N_SHADING] -= _gram_vector(ridge, shading)       # ridge is symmetric
        step, ok = _solve(_gram(jac, jac) + penalty, gradient)
        if not ok:
            return _not_posed(cx, cy, n)
        length = math.hypot(step[N_SHADING], step[N_SHADING + 1])
        if length > 1.0:
            step = step / length
        shading = shading + step[:N_SHADING]
        cx += step[N_SHADING]
        cy += step[N_SHADING + 1]
        _render(xs, ys, cx, cy, a, bu, bv, steps, sub, psf, cover, dcover, basis, dbasis)
        if np.count_nonzero(cover) < k:
            return _not_posed(cx, cy, n)
        if length < converged:
            break
    _residuals(obs, bg, cover, basis, shading, res)
    cost = np.sum((res * weight) ** 2) + np.sum(shading * _gram_vector(ridge, shading))
    return True, cx, cy, cost, shading, res, cover


def fit_outline(grey, background, usable, start, ball, iterations=6, curvature_weight=0.0,
                image_blur=0.0):
    """Centre (u, v) of a ball of known outline and motion blur (``ball``, a
    :class:`BallImage`) in the grey patch ``grey`` (float; ``start``, ``ball``'s outline and
    blur in the patch's pixel coordinates), fitted from ``start``, and the sum of the squared
    residuals and the curvature penalty; or None when the fit fails (or ends more than a
    radius from ``start``).

    Each pixel is modelled as the background (``background``) where the ball does not cover
    it and the ball's own brightness where it does, mixed in proportion to the coverage,
    I = G (1 - c) + c B (:func:`ball_model`). For a centre, the ball's brightness B is solved
    by linear least squares; the centre is moved by Gauss-Newton on what remains (variable
    projection). A pixel tells where the outline is only in proportion to the contrast B - G
    there, so a shaded side as dark as the background behind it carries no weight and does
    not pull the centre: the known outline places the centre from the sides that are seen.
    ``usable`` (bool, the patch's shape): pixels that may be used (not a shadow). ``grey``
    and ``background`` in proportion to light (the camera's response undone).

    ``curvature_weight`` > 0 adds the penalty s^T W s of :func:`curvature_penalty` (W from
    the pixels' basis at ``start``) to the squared residuals: a ridge on the brightness's
    curvature beyond a linear shading (:attr:`DetectorConfig.curvature_weight`).
    ``image_blur``: the camera's blur, px (:func:`ball_model`).

    The whole fit is one compiled kernel (numba, run without the GIL, so that the camera
    threads fit in parallel)."""
    fit = OutlineFit(grey, background, usable, ball, iterations, curvature_weight,
                     image_blur).fit(start)
    return None if fit is None else fit[:2]


class OutlineFit:
    """:func:`fit_outline` on one patch from as many starts as wanted (:meth:`fit`): the
    patch's usable pixels are gathered once (``usable`` of ``grey`` and ``background``, or
    given gathered: ``pixels`` = (observed, background, x, y), float64 arrays).

    ``encoded`` = (background, gamma, blur): the camera blurs its encoded values by ``blur``
    px after its response 255 (L / 255)^(1 / gamma) (:attr:`DetectorConfig.encoded_blur`);
    ``background`` is the whole patch's (2-D, light). Each pixel is then modelled as
    f^-1(g * f(L)), L the light image the fit models (``image_blur`` its blur) and g the
    encoded values' Gaussian blur: the fit models g * L (blurred by both) and takes from the
    observed light the difference f^-1(g * f(L)) - g * L, which only the response's
    curvature makes (:func:`encoded_blur_offsets`), computed at the last fit's centre and
    shading and refitted :data:`REFITS` times (the difference moves little with
    them: four rounds instead of two moved the independent renderer's heights by under
    0.01 mm). None: a linear camera, or no blur after the response.

    ``inside_huber`` > 0 (:attr:`DetectorConfig.inside_huber`): the refits of
    :meth:`refine` weight the pixels inside the ball by :func:`inside_weights` of the last
    fit's residuals (their square roots, passed to each refit); the fits of :meth:`with_blur`
    weight every pixel alike, so that the costs of the blurs or exposures they compare are of the
    same sum."""

    def __init__(self, grey, background, usable, ball, iterations=6, curvature_weight=0.0,
                 image_blur=0.0, pixels=None, encoded=None, inside_huber=0.0):
        if pixels is None:
            ys, xs = np.nonzero(usable)
            pixels = (grey[ys, xs].astype(float), background[ys, xs].astype(float),
                      xs.astype(float), ys.astype(float))
        self.obs, self.bg, self.xs, self.ys = pixels
        self.alike = np.ones(self.xs.size)         # every pixel's weight alike
        self.inside_huber = inside_huber
        self.ball = ball
        self.image_blur = image_blur
        self.encoded = encoded
        self.whitening = _whiten(ball.outline)
        self.blur = (float(ball.blur[0]), float(ball.blur[1]))
        self.sampling = _sampling(
            ball, image_blur if encoded is None else math.hypot(image_blur, encoded[2]))
        self.options = (float(curvature_weight), int(iterations), CONVERGED)
        self.scale = _outline_extent(ball.outline)[1]
        self.up = None if ball.up is None else np.asarray(ball.up, dtype=float)

    def fit(self, start, refine=True):
        """(centre, cost, lit_from_below, shading, residuals, cover) of the fit from
        ``start`` (patch pixels), or None (:func:`fit_outline`); ``lit_from_below``
        (:data:`LIT_FROM_BELOW_COS`) only when the ball's ``up`` is known, else False;
        ``residuals`` and ``cover`` each pixel's (observed minus modelled, and the ball's
        coverage). Not ``refine``: without the encoded values' blur's difference
        (``encoded``) and the weights inside the ball (``inside_huber``), for a first choice
        among starts (:meth:`refine` takes them on)."""
        fit = self._fit_once(self.obs, start)
        return self.refine(fit) if refine and fit is not None else fit

    def refine(self, fit):
        """The fit ``fit`` (from :meth:`fit`) refitted with the encoded values' blur
        (``encoded``: :data:`REFITS` times) and with the pixels inside the ball weighted by
        how well the last fit explains them (``inside_huber`` > 0: :func:`inside_weights`;
        :data:`INSIDE_REFITS` times without ``encoded``); ``fit`` when neither applies, None
        when a refit fails."""
        if self.encoded is not None:
            refits = REFITS
        else:
            refits = INSIDE_REFITS if self.inside_huber > 0.0 else 0
        obs, weight = self.obs, self.alike
        background, gamma, blur = self.encoded or (None, None, None)
        for _ in range(refits):
            if self.encoded is not None:
                obs = self.obs - encoded_blur_offsets(
                    fit[0], fit[3], self.ball, self.whitening, background, self.xs, self.ys,
                    self.image_blur, blur, gamma)
            if self.inside_huber > 0.0:
                weight = inside_weights(fit[4], fit[5], self.inside_huber)
            fit = self._fit_once(obs, fit[0], weight)
            if fit is None:
                return None
        return fit

    def _fit_once(self, obs, start, weight=None):
        if self.xs.size < 12:
            return None
        ok, u, v, cost, shading, res, cover = _fit(
            obs, self.bg, self.xs, self.ys, float(start[0]), float(start[1]), self.whitening,
            *self.blur, *self.sampling, *self.options,
            self.alike if weight is None else weight)
        centre = np.array([u, v])
        if (not ok or not np.all(np.isfinite(centre))
                or np.hypot(*(centre - start)) > max(self.scale, 1.0)):
            return None
        return centre, float(cost), self._lit_from_below(shading), shading, res, cover

    def with_blur(self, image_blur=None, motion=1.0):
        """The same fit of the same pixels with the camera blur ``image_blur`` (px; None: this
        fit's) and the ball's motion over the exposure ``motion`` times this fit's (the
        exposure that many times as long)."""
        curvature_weight, iterations, _ = self.options
        ball = self.ball if motion == 1.0 else dataclasses.replace(
            self.ball, blur=(motion * self.blur[0], motion * self.blur[1]))
        return OutlineFit(None, None, None, ball, iterations, curvature_weight,
                          self.image_blur if image_blur is None else image_blur,
                          (self.obs, self.bg, self.xs, self.ys), self.encoded)

    def _lit_from_below(self, shading):
        if self.up is None:
            return False
        # The brightness's gradient over the image: d/d(pixel offset) of s1 wx + s2 wy, w = A d.
        across = shading[1:3]
        gradient = self.whitening.T @ across
        size = math.hypot(*gradient)
        return bool(math.hypot(*across) > SHADING_MIN * abs(shading[0])
                    and gradient @ self.up < -LIT_FROM_BELOW_COS * size)


def estimate_image_blur(fits, blurs=IMAGE_BLUR_GRID, motion=1.0):
    """The camera's blur (:attr:`DetectorConfig.image_blur`), px, that explains the pixels of
    the outline fits ``fits`` best, and the number of fits it rests on: (blur, n), or
    (None, 0) when no fit succeeds at every blur.

    ``fits``: (:class:`OutlineFit`, centre) pairs, the fitted candidates of one camera
    (:attr:`BallDetector.fits`). Each is fitted again from its centre with every blur of
    ``blurs`` (evenly spaced, increasing; and the ball's motion over the exposure ``motion``
    times its own: :func:`estimate_exposure`'s ratio); the blur of least summed cost
    (:func:`_least_cost`). A blur the camera does not have leaves a residual along the
    whole outline, on the lit and the shaded side alike, so the fits' cost is least near the
    camera's own (docs/perception.md, "The cameras' blur, estimated": within about 0.2 px of
    the blur that places the ball best on the scenes of two renderers written apart from
    tt_perception.synth)."""
    return _least_cost(fits, blurs, lambda fitter, blur: fitter.with_blur(blur, motion))


def estimate_exposure(fits, exposure, longest, steps=EXPOSURE_STEPS):
    """The exposure (:attr:`DetectorConfig.exposure`), s, that explains the pixels of the
    outline fits ``fits`` best, and the number of fits it rests on: (exposure, n), or
    (None, 0) when no fit succeeds at every exposure tried.

    ``fits`` as :func:`estimate_image_blur`'s, fitted with ``exposure`` (s): each is fitted
    again with the ball's motion over the exposure scaled to every exposure of ``steps``
    evenly spaced from 0 to ``longest`` (s; the frame period: a camera does not expose for
    longer); the exposure of least summed cost (:func:`_least_cost`). The ball's streak is
    as long as its image speed times the exposure, along its motion only, so it is told
    apart from the camera's own blur, which is the same across the motion
    (docs/perception.md, "The cameras' exposure, estimated")."""
    grid = np.linspace(0.0, longest, steps)
    return _least_cost(fits, grid, lambda fitter, e: fitter.with_blur(motion=e / exposure))


def estimate_exposure_and_blur(fits, exposure, longest, rounds=4):
    """The exposure (s) and the camera's blur (px) that explain the pixels of the outline
    fits ``fits`` (fitted with ``exposure``, s) best together, and the number of fits they
    rest on: (exposure, blur, n), or (None, None, 0).

    The two trade against each other (a streak shorter than the ball's is explained best
    by the most blur tried; a sharp camera's ball fitted with 0.6 px of blur by no motion
    at all), so they are found in turn: the blur (:func:`estimate_image_blur`) with the
    exposure found last (first ``exposure``), then the exposure (:func:`estimate_exposure`,
    up to ``longest``) with that blur, each over its whole grid, for at most ``rounds``
    rounds or until neither moves by more than a quarter of its grid's step
    (docs/perception.md, "The cameras' exposure, estimated")."""
    blur_step = IMAGE_BLUR_GRID[1] - IMAGE_BLUR_GRID[0]
    seconds, blur = exposure, None
    for _ in range(rounds):
        found_blur, n = estimate_image_blur(fits, motion=seconds / exposure)
        if found_blur is None:
            return None, None, 0
        found, n = estimate_exposure([(f.with_blur(found_blur), c) for f, c in fits],
                                     exposure, longest)
        if found is None:
            return None, None, 0
        settled = (blur is not None and abs(found_blur - blur) < 0.25 * blur_step
                   and abs(found - seconds) < 0.25 * longest / (EXPOSURE_STEPS - 1))
        seconds, blur = found, found_blur
        if settled:
            break
    return seconds, blur, n


def _least_cost(fits, values, refit):
    """The value of ``values`` (evenly spaced, increasing) whose fits ``refit(fitter,
    value)`` from each of ``fits``' centres have the least summed cost, moved to the vertex
    of the parabola through it and its two neighbours when it is not at either end; over
    the fits that succeed at every value: (value, their number), or (None, 0)."""
    values = np.asarray(values, dtype=float)
    costs = []
    for fitter, centre in fits:
        row = []
        for value in values:
            fit = refit(fitter, float(value)).fit(centre)
            if fit is None:
                break
            row.append(fit[1])
        else:
            costs.append(row)
    if not costs:
        return None, 0
    total = np.sum(costs, axis=0)
    i = int(np.argmin(total))
    best = values[i]
    if 0 < i < values.size - 1:
        left, mid, right = total[i - 1:i + 2]
        curvature = left - 2.0 * mid + right
        if curvature > 0.0:
            best += 0.5 * (left - right) / curvature * (values[i + 1] - values[i])
    return float(best), len(costs)


def warm_up():
    """Load the compiled kernels (numba) of :func:`ball_model`, :func:`fit_outline`, the
    silhouette's centre, the blobs' measures, the fit's pixels and :func:`light_gain` before
    the first ball needs them."""
    ball = BallImage(0.0, 0.0, np.eye(2) * 3.0, np.array([1.0, 0.0]))
    ball_model(np.zeros(1), np.zeros(1), (0.0, 0.0), ball)
    patch = np.zeros((9, 9))
    patch[2:7, 2:7] = 100.0
    fit_outline(patch, np.zeros((9, 9)), np.ones((9, 9), bool), (4.0, 4.0), ball,
                curvature_weight=1.0)
    colour = np.repeat(patch.astype(np.uint8)[:, :, None], 3, axis=2)
    _silhouette_moments(colour, np.zeros((9, 9, 3), np.float32), np.ones((2, 2), np.uint8), 4,
                        4, 14.0)
    seed = np.ones((2, 2), np.uint8)
    _blob_measures(seed, seed, np.zeros((6, 6), np.uint8), np.zeros((6, 6, 3), np.uint8),
                   np.zeros((6, 6, 3), np.float32), 2, 2, 22.0, True, True)
    _usable_pixels(np.zeros((6, 6), np.uint8), _NO_PATCH, _NO_BACKGROUND,
                   np.zeros((6, 6), np.float32), 2.5, 2.5, 3.0, False)
    grey = np.zeros((6, 6), np.uint8)
    light_gains(np.zeros((6, 6, 3), np.uint8), grey)
    light_gains(grey, grey)
    light_gain(grey, grey)
    exposure_level(grey, np.zeros((6, 6, 3), np.float32))


@njit(cache=True, nogil=True)
def _silhouette_moments(patch, background, seed, sx, sy, threshold):
    """Kernel of :meth:`BallDetector._silhouette_centre` on a BGR ``patch`` (uint8) and its
    colour ``background`` (float32), the blob ``seed`` (uint8) at (sx, sy) in it: the
    centroid (u, v) of the silhouette's coverage and its central second moments over its
    weight (cxx, cyy, cxy), patch pixels; or None when its weight is 0.

    The silhouette: the pixels whose largest change over B, G, R exceeds ``threshold`` and
    that are not darker in all three (a shadow), 8-connected to the seed (which belongs to
    it). Coverage: 1 inside (the pixels whose 3 x 3 neighbourhood, edges replicated, is all
    silhouette); on its outline the pixel's change over the mean change of the inside pixels
    in its 5 x 5 neighbourhood (edges mirrored), clipped to [0, 1] (a mixed pixel changes in
    proportion to the part the ball covers, lit or shaded), or over the seed's median change
    when no inside pixel is near."""
    h, w = patch.shape[0], patch.shape[1]
    if sx < 0 or sy < 0 or sx + seed.shape[1] > w or sy + seed.shape[0] > h:
        raise ValueError('the seed is not inside the patch')
    size = np.empty((h, w))
    sil = np.zeros((h, w), np.bool_)
    for y in range(h):
        for x in range(w):
            largest = -np.inf
            biggest = 0.0
            for c in range(3):
                d = float(patch[y, x, c]) - float(background[y, x, c])
                largest = max(largest, d)
                biggest = max(biggest, abs(d))
            size[y, x] = biggest
            sil[y, x] = biggest > threshold and largest >= 0.0
    # The silhouette's part connected to the seed: a flood fill from the seed's pixels.
    region = np.zeros((h, w), np.bool_)
    stack = np.empty(h * w, np.int64)
    top = 0
    seed_sizes = np.empty(seed.size)
    n_seed = 0
    for y in range(seed.shape[0]):
        for x in range(seed.shape[1]):
            if seed[y, x]:
                seed_sizes[n_seed] = size[sy + y, sx + x]
                n_seed += 1
                sil[sy + y, sx + x] = True
                if not region[sy + y, sx + x]:
                    region[sy + y, sx + x] = True
                    stack[top] = (sy + y) * w + sx + x
                    top += 1
    while top > 0:
        top -= 1
        y, x = divmod(stack[top], w)
        for yy in range(max(y - 1, 0), min(y + 2, h)):
            for xx in range(max(x - 1, 0), min(x + 2, w)):
                if sil[yy, xx] and not region[yy, xx]:
                    region[yy, xx] = True
                    stack[top] = yy * w + xx
                    top += 1
    inner = np.zeros((h, w), np.bool_)
    for y in range(h):
        for x in range(w):
            if region[y, x]:
                inside = True
                for yy in range(y - 1, y + 2):
                    for xx in range(x - 1, x + 2):
                        if not region[min(max(yy, 0), h - 1), min(max(xx, 0), w - 1)]:
                            inside = False
                inner[y, x] = inside
    fallback = np.median(seed_sizes[:n_seed]) if n_seed else 0.0
    m00 = m10 = m01 = 0.0
    cover = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            if inner[y, x]:
                cover[y, x] = 1.0
            elif region[y, x]:
                near, count = 0.0, 0
                for yy in range(y - 2, y + 3):
                    ry = -yy if yy < 0 else (2 * h - 2 - yy if yy >= h else yy)
                    ry = min(max(ry, 0), h - 1)
                    for xx in range(x - 2, x + 3):
                        rx = -xx if xx < 0 else (2 * w - 2 - xx if xx >= w else xx)
                        rx = min(max(rx, 0), w - 1)
                        if inner[ry, rx]:
                            near += size[ry, rx]
                            count += 1
                local = near / count if count else fallback
                cover[y, x] = min(max(size[y, x] / max(local, 1e-6), 0.0), 1.0)
            m00 += cover[y, x]
            m10 += x * cover[y, x]
            m01 += y * cover[y, x]
    if not m00 > 0.0:
        return None
    cu, cv = m10 / m00, m01 / m00
    cxx = cyy = cxy = 0.0
    for y in range(h):
        for x in range(w):
            c = cover[y, x]
            if c != 0.0:
                cxx += c * (x - cu) ** 2
                cyy += c * (y - cv) ** 2
                cxy += c * (x - cu) * (y - cv)
    return cu, cv, cxx / m00, cyy / m00, cxy / m00


REFITS = 2
"""Refits of :meth:`OutlineFit.refine` with the encoded values' blur (``encoded``)."""
INSIDE_REFITS = 1
"""Refits of :meth:`OutlineFit.refine` weighting the pixels inside the ball
(:attr:`DetectorConfig.inside_huber`) where no encoded values' blur asks for refits: one
(synth's hall, orange ball at 1280x720: heights -0.24 mm, -0.20 with two, for another
0.13 ms a ball)."""
INSIDE_COVER = 0.99
"""Coverage of a pixel by the ball from which it counts as inside the ball, its value
telling only the ball's brightness (:func:`inside_weights`)."""
SCALE_FLOOR = 1.0
"""Least scale of the fit's residuals in :func:`inside_weights`, grey levels (of light): a
camera's read noise and rounding give at least this; on a noiseless render the scale would be
the model's own mismatch, and a threshold in its units would weight down every pixel."""


def inside_weights(residuals, cover, threshold):
    """Square roots of the pixels' weights in the outline fit's refits (:meth:`OutlineFit.
    refine`): Huber's, min(1, threshold s / |r|), for the pixels the ball covers whole
    (``cover`` at least :data:`INSIDE_COVER`) and 1 for the others; ``residuals`` r the last
    fit's (grey levels of light), s their robust scale (1.4826 times their median absolute
    deviation, at least :data:`SCALE_FLOOR`). A pixel inside the ball tells only its
    brightness, which the quadratic shading follows only roughly: a specular highlight, a
    spot too small and too bright for it, is fitted at the cost of the shading near the
    outline, and moved the centre (docs/perception_measured.md, "A specular highlight")."""
    scale = max(1.4826 * float(np.median(np.abs(residuals - np.median(residuals)))),
                SCALE_FLOOR)
    huber = np.sqrt(np.minimum(1.0, threshold * scale / np.maximum(np.abs(residuals), 1e-12)))
    return np.where(cover >= INSIDE_COVER, huber, 1.0)


def encoded_blur_offsets(centre, shading, ball, whitening, background, xs, ys, image_blur,
                         encoded_blur, gamma):
    """What a blur of the encoded values adds to the light a pixel seems to have got, beyond
    the same blur of the light: f^-1(g * f(L)) - g * L at the pixels (xs, ys) (float
    arrays) of a patch whose background light is ``background`` (2-D), for the ball ``ball``
    (:class:`BallImage`, ``whitening`` its outline's :func:`_whiten`) centred at ``centre``
    with the brightness ``shading`` (:func:`ball_model`, blurred by ``image_blur`` px), the
    response f(L) = 255 (L / 255)^(1 / ``gamma``) and g a Gaussian of ``encoded_blur`` px
    over the patch's pixel grid (its edge's pixels repeated). Light in grey levels. Zero
    for a linear response; a blur of the encoded values brings an edge's half-way light
    toward its bright side by more where the edge's contrast ratio is larger."""
    h, w = background.shape
    gy, gx = np.mgrid[0:h, 0:w]
    cover, basis, _, _ = ball_model(gx.ravel().astype(float), gy.ravel().astype(float),
                                    centre, ball, whitening, image_blur)
    light = background.ravel() * (1.0 - cover) + basis @ shading
    light = np.clip(light, 0.0, 255.0).reshape(h, w)
    size = 2 * int(math.ceil(3.0 * encoded_blur)) + 1
    blurred = cv2.GaussianBlur(light, (size, size), encoded_blur,
                               borderType=cv2.BORDER_REPLICATE)
    encoded = cv2.GaussianBlur(255.0 * (light * (1.0 / 255.0)) ** (1.0 / gamma), (size, size),
                               encoded_blur, borderType=cv2.BORDER_REPLICATE)
    offsets = 255.0 * (encoded * (1.0 / 255.0)) ** gamma - blurred
    return offsets[ys.astype(np.intp), xs.astype(np.intp)]


def _grey(image):
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def _any_channel(per_channel):
    """255 where any of B, G, R of a 0/255 image is 255, else 0 (uint8, H x W)."""
    # A channel at 255 weighs at least 0.114 * 255 in the grey of the 0/255 image.
    return cv2.compare(cv2.cvtColor(per_channel, cv2.COLOR_BGR2GRAY), 0, cv2.CMP_GT)


def colour_only_blobs(window, background, grey_mask, threshold, fewest):
    """The blobs (255, else 0; uint8, H x W) of the pixels of the BGR ``window`` that differ
    from the BGR ``background`` (uint8, same shape) by more than ``threshold`` in some
    channel and are not darker in all three (a shadow), whose 8-connected region (with the
    pixels of ``grey_mask``, those changed in grey) holds fewer than ``fewest`` pixels of
    ``grey_mask``: a ball only its colour tells from what is behind it, but for a sliver of
    its lit side. A region that more grey change reaches is left to the grey blobs as it
    was: the colour would join a ball's shaded side to its contact shadow beside it, or take
    in the shaded half of a ball that the grey shows in full."""
    _, changed = cv2.threshold(cv2.absdiff(window, background), threshold, 255,
                               cv2.THRESH_BINARY)
    colour = _any_channel(changed)
    if not cv2.countNonZero(colour & ~grey_mask):        # the common case: nothing more
        return np.zeros_like(grey_mask)
    colour &= _any_channel(cv2.compare(window, background, cv2.CMP_GE))
    n, labels = cv2.connectedComponents(colour | grey_mask, connectivity=8)
    reached = np.bincount(labels[grey_mask > 0], minlength=n) >= fewest
    reached[0] = True
    return np.where(reached[labels], 0, 255).astype(np.uint8)


GAIN_DEADBAND = 0.03
"""A gain of the light (:func:`light_gain`) within this of 1 is taken as 1, the background
used as it is: it moves no level by more than 7.5, a third of ``diff_threshold``, so it
makes no blob. Applied, the 1.3 % ripple of the independent renderer's lamps (as its camera
encodes it) put its orange 640x480 balls' heights 0.06-0.09 mm higher (to +0.31 and +0.32
mm, over issue 15's 0.3), though the frame's gain is measured to 0.05 %: the background is
learnt every third frame, at one phase of a 100 Hz ripple at 150 fps, and the camera's
``encoded_blur`` (0.5 px) was chosen on those scenes as they were."""
GAIN_STEP = 16
"""Every how many pixels of both axes of a frame :func:`light_gain` reads."""
GAIN_RANGE = (0.5, 2.0)
"""The light's gain is held within this range."""


GAIN_TILES = (4, 6)
"""Rows and columns of the grid of parts of a frame whose light is measured apart
(:func:`light_gains`)."""
GAIN_TILE_DEADBAND = 0.06
"""The parts' gains are used when one differs from the whole frame's by more than this (the
scalar gain else): twice :data:`GAIN_DEADBAND`, so that a steady light's scenes, whose parts
a ball, its shadow or a moving robot shift by a few percent, keep the one gain."""
GAIN_TILE_AGREEMENT = (0.06, 0.6)
"""A part's gain counts when this share (second) of its pixels' ratios lie within this
(first) of their median: under a lamp the table, floor and walls of a part change alike; a
part half covered by a person moving has no one ratio (its gain is then the frame's)."""


def light_gain(frame, background, step=GAIN_STEP):
    """The light's gain in a ``frame`` (BGR or grey, uint8) against its grey ``background``
    (uint8, the frame's size): the median ratio of the two, the frame's grey level over the
    background's, over every ``step``-th pixel of both axes whose levels are both within
    16-250 (a ratio of dark pixels is noise, a clipped one is no ratio), within
    :data:`GAIN_RANGE`; 1 within :data:`GAIN_DEADBAND` of it, or when fewer than 32 pixels
    count. 0.05 ms a 640 x 480 frame.

    Lamps on alternating current flicker at twice the mains frequency (100 or 120 Hz), and a
    camera at 150 fps with a 2 ms exposure catches each frame at another phase: a hall's LED
    or fluorescent light varying 10 % made a white table line differ from the background by
    more than ``diff_threshold``, and such blobs beside the ball cost frames of a track
    (synth's hall, white ball at 640x480: 93 % of the frames with a state, 81 % at 30 %).
    The background times the gain is what the frame shows where no ball is. The whole frame
    is read, not the window searched: around the ball its shadow and the table it darkens
    moved the median 2-6 % on a steady light (synth's hall)."""
    return light_gains(frame, background, (1, 1), step)[0]


def light_gains(frame, background, tiles=GAIN_TILES, step=GAIN_STEP):
    """``(gain, grid)``: :func:`light_gain` of the whole ``frame``, and the gains of the
    ``tiles`` (rows, columns) parts of the frame where they differ, float32 (rows,
    columns), else None. Lamps on the three phases of the mains, each lighting a part of
    the hall, flicker out of step: the whole frame's light hardly changes (the three sum to
    a steady one) while each part's changes by the flicker's depth (synth's hall, white,
    640x480, three lamps along the width flickering 20 %: 95.5 % of the frames with a state
    with the one gain, 100 % part by part; in three sectors around the image's centre 84 and
    93 %). A part's gain is its pixels' median ratio, within :data:`GAIN_RANGE`, or the
    frame's where fewer than 32 pixels count or they do not agree
    (:data:`GAIN_TILE_AGREEMENT`); the grid is given only when one part is more than
    :data:`GAIN_TILE_DEADBAND` off the frame's gain."""
    if frame.ndim == 2:
        frame = frame[:, :, None]
    rows, cols = tiles
    near, share = GAIN_TILE_AGREEMENT
    ratios = _median_ratios(frame, background, step, rows, cols, near, share)
    whole = ratios[-1]
    gain = 1.0 if abs(whole - 1.0) <= GAIN_DEADBAND else min(max(whole, GAIN_RANGE[0]),
                                                               GAIN_RANGE[1])
    if rows * cols == 1:
        return gain, None
    parts = np.clip(np.where(np.isfinite(ratios[:-1]), ratios[:-1], gain), *GAIN_RANGE)
    if np.max(np.abs(parts - gain)) <= GAIN_TILE_DEADBAND:
        return gain, None
    return gain, parts.reshape(rows, cols).astype(np.float32)


@njit(cache=True, nogil=True)
def _median_ratios(frame, background, step, rows, cols, near, share):
    """Kernel of :func:`light_gains` (``frame`` H x W x 1 or 3; grey as OpenCV weighs B, G,
    R): the median ratio of each of the rows x cols parts, row by row (NaN where fewer than
    32 pixels count or fewer than ``share`` of them lie within ``near`` of the median), and
    last the whole frame's (1.0 when fewer than 32 pixels count)."""
    h, w = background.shape
    size = (h // step + 1) * (w // step + 1)
    ratios = np.empty(size, np.float64)
    part = np.empty(size, np.int64)
    n = 0
    for y in range(0, h, step):
        for x in range(0, w, step):
            if frame.shape[2] == 3:
                level = (0.114 * frame[y, x, 0] + 0.587 * frame[y, x, 1]
                         + 0.299 * frame[y, x, 2])
            else:
                level = float(frame[y, x, 0])
            b = float(background[y, x])
            if 16.0 <= b <= 250.0 and 16.0 <= level <= 250.0:
                ratios[n] = level / b
                part[n] = (y * rows // h) * cols + x * cols // w
                n += 1
    parts = rows * cols
    out = np.full(parts + 1, np.nan)
    out[-1] = np.median(ratios[:n]) if n >= 32 else 1.0
    if parts == 1:
        return out
    start = np.zeros(parts + 1, np.int64)      # each part's ratios together, in order
    for i in range(n):
        start[part[i] + 1] += 1
    for k in range(parts):
        start[k + 1] += start[k]
    filled = start[:-1].copy()
    grouped = np.empty(n, np.float64)
    for i in range(n):
        grouped[filled[part[i]]] = ratios[i]
        filled[part[i]] += 1
    for k in range(parts):
        mine = grouped[start[k]:start[k + 1]]
        if len(mine) < 32:
            continue
        median = np.median(mine)
        agree = 0
        for r in mine:
            agree += abs(r - median) <= near * median
        if agree >= share * len(mine):
            out[k] = median
    return out


HIDDEN_MARGIN = 2
"""Pixels around a blob's box that :func:`_blob_measures` reads (its 3 x 3 dilation's ring)."""
_GROW_KERNEL = np.ones((5, 5), np.uint8)
"""The dilation that grows the blobs' mask by 2 pixels before the background update skips
it (BallDetector._update_background)."""
_NO_PATCH = np.zeros((1, 1, 3), np.uint8)
_NO_BACKGROUND = np.zeros((1, 1, 3), np.float32)


@njit(cache=True, nogil=True)
def _blob_measures(sub, diff, grey, patch, background, px, py, threshold, colour,
                   with_background):
    """What :meth:`BallDetector._blobs` measures of one blob, in one compiled call: ``sub``
    (uint8, 1 on the blob) and ``diff`` (uint8, its change against the background) on the
    blob's box; ``grey`` (uint8), ``patch`` (BGR uint8) and ``background`` (the colour
    background, float32) on the box and a margin, the box at (px, py) in them.

    Returns (total, cu, cv, cxx, cyy, cxy, hidden, B, G, R, bg B, bg G, bg R):
    - total, (cu, cv): the sum of the blob's change and its change-weighted centroid in the
      box (cv2.moments of max(diff, 1) * sub: a pixel changed in colour alone weighs 1);
    - cxx, cyy, cxy: the blob's central second moments over its area (cv2.moments of sub,
      the same sums and formulas);
    - hidden: the fraction of the pixels around the blob (its 3 x 3 dilation's ring) whose
      grey level is within ``threshold`` of the blob's mean (rounded): background as bright
      as the ball, where the blob may have lost part of it;
    - with ``colour``: the mean colour of the blob's lit half (its pixels at least as bright
      as their median grey level; of its pixels whose grey level changed by more than
      ``threshold`` where it has some) and, ``with_background``, the background's mean
      there."""
    bh, bw = sub.shape
    out = np.zeros(13)
    # Sums of integers: exact in float64, as OpenCV's moments are.
    m00 = m10 = m01 = 0.0
    s00 = s10 = s01 = s20 = s11 = s02 = 0.0
    grey_sum = 0.0
    values = np.empty(bh * bw, np.uint8)     # the blob's grey levels
    n = 0
    changed_values = np.empty(bh * bw, np.uint8)    # those of its pixels changed in grey
    changed = 0
    for y in range(bh):
        for x in range(bw):
            if sub[y, x]:
                v = max(float(diff[y, x]), 1.0)
                m00 += v
                m10 += x * v
                m01 += y * v
                s00 += 1.0
                s10 += x
                s01 += y
                s20 += x * x
                s11 += x * y
                s02 += y * y
                g = grey[py + y, px + x]
                values[n] = g
                n += 1
                grey_sum += g
                if v > threshold:
                    changed_values[changed] = g
                    changed += 1
    if m00 <= 0.0 or n == 0:
        return out
    out[0] = m00
    out[1] = m10 / m00
    out[2] = m01 / m00
    inv = 1.0 / s00
    cx, cy = s10 * inv, s01 * inv
    out[3] = (s20 - s10 * cx) / s00
    out[4] = (s02 - s01 * cy) / s00
    out[5] = (s11 - s10 * cy) / s00
    # The ring: pixels 8-adjacent to the blob, not in it, within the patch.
    level = np.rint(grey_sum * inv)
    h, w = grey.shape
    ring = alike = 0
    for y in range(max(py - 1, 0), min(py + bh + 1, h)):
        for x in range(max(px - 1, 0), min(px + bw + 1, w)):
            by, bx = y - py, x - px
            if 0 <= by < bh and 0 <= bx < bw and sub[by, bx]:
                continue
            near = False
            for yy in range(max(by - 1, 0), min(by + 2, bh)):
                for xx in range(max(bx - 1, 0), min(bx + 2, bw)):
                    if sub[yy, xx]:
                        near = True
            if near:
                ring += 1
                if abs(float(grey[y, x]) - level) < threshold:
                    alike += 1
    out[6] = alike / ring if ring else 0.0
    if colour:
        # Of the pixels whose grey level changed, where there are some: the rest of a blob
        # that its colour completed (colour_only_blobs) is the ball's shaded side.
        if changed:
            values, n = changed_values, changed
        ordered = np.sort(values[:n])
        median = (float(ordered[n // 2]) if n % 2 else
                  0.5 * (float(ordered[n // 2 - 1]) + float(ordered[n // 2])))
        lit = 0.0
        sums = np.zeros(6)
        for y in range(bh):
            for x in range(bw):
                if (sub[y, x] and grey[py + y, px + x] >= median
                        and (not changed or diff[y, x] > threshold)):
                    lit += 1.0
                    for c in range(3):
                        sums[c] += patch[py + y, px + x, c]
                        if with_background:
                            sums[3 + c] += background[py + y, px + x, c]
        for c in range(6):
            out[7 + c] = sums[c] * (1.0 / lit)
    return out


@njit(cache=True, nogil=True)
def _usable_pixels(grey, patch, colour_background, background, u, v, reach, shadows):
    """The pixels of a patch a fit may use (:meth:`BallDetector._fit_centre`), gathered:
    (grey level, background level) as float32 and (x, y) as float64, of the pixels within
    ``reach`` of (u, v) (patch pixels) and, with ``shadows``, not darker than the colour
    background in all three channels of the BGR ``patch`` (a shadow)."""
    h, w = grey.shape
    obs = np.empty(h * w, np.float32)
    bg = np.empty(h * w, np.float32)
    xs = np.empty(h * w)
    ys = np.empty(h * w)
    n = 0
    for y in range(h):
        for x in range(w):
            if not math.hypot(x - u, y - v) <= reach:
                continue
            if shadows:
                lit = False
                for c in range(3):
                    if np.float32(patch[y, x, c]) >= colour_background[y, x, c]:
                        lit = True
                if not lit:
                    continue
            obs[n] = grey[y, x]
            bg[n] = background[y, x]
            xs[n] = x
            ys[n] = y
            n += 1
    return obs[:n], bg[:n], xs[:n], ys[:n]


def sized_for(config, focal, ball_radius=BALL_RADIUS_M):
    """``config`` with its pixel sizes left at 0 set for a camera of focal length ``focal``
    (pixels) and a ball of ``ball_radius`` (m): ``max_width`` the ball's diameter at
    NEAREST_BALL_M, ``max_area`` its square and ``roi_half_size`` 4/3 of it (30 px, 900 px
    and 40 px at 554 px)."""
    width = config.max_width or 2.0 * ball_radius * focal / NEAREST_BALL_M
    return dataclasses.replace(config, max_width=width,
                               max_area=config.max_area or round(width ** 2),
                               roi_half_size=config.roi_half_size or round(width * 4.0 / 3.0))


class BallDetector:
    """Detector of one camera (it keeps that camera's background). ``focal``: the camera's
    focal length, pixels, for the pixel sizes of ``config`` left at 0 (:func:`sized_for`)."""

    def __init__(self, config=None, focal=REFERENCE_FOCAL_PX, ball_radius=BALL_RADIUS_M):
        self.config = sized_for(config or DetectorConfig(), focal, ball_radius)
        self.background = None
        self._bg8 = None
        self._bg_colour = None
        self._bg_colour8 = None   # _bg_colour rounded to uint8, for colour_only_blobs
        self._count = 0
        self._pending = None
        self.fits = None
        """A list (or a bounded deque) to append each fitted candidate's
        (:class:`OutlineFit`, centre) to, for :func:`estimate_image_blur`; None: they are
        not kept."""
        self.colourless = None
        """Whether this camera's frames are grey given as BGR (its first frame's three
        channels equal: a monochrome camera's mono8, a grey video): they are then taken as
        grey, and the ball's ``colour`` cannot be checked (None before the first frame)."""
        self.gain = 1.0
        """The light's gain in the frame last searched against the background
        (:func:`light_gain`)."""
        self.gain_grid = None
        """Its parts' gains where they differ (:func:`light_gains`), else None."""
        self._gain_map = None     # gain_grid over the frame's pixels, made when first needed
        self.level = 1.0
        """How brightly the camera is exposed (:func:`exposure_level`, measured on its
        background): a blob's colour and its change against the background are divided by
        it, times the frame's :attr:`gain`, before they are judged (1 at most)."""
        self._updates = 0
        self.colour_refused = 0
        """Blobs refused for their colour alone (:func:`colour_matches`)."""
        self.refused_colours = collections.deque(maxlen=100)
        """The last of their colours (B, G, R, divided by ``white_bgr``), for a warning."""

    def detect(self, frame, roi_centre=None, update_background=True, expected=None,
               search=False, later=False):
        """Ball candidates in ``frame`` (H x W x 3 BGR or H x W grey uint8).

        ``roi_centre`` (u, v): search only the window of ``roi_half_size`` around it.
        ``update_background``: False for a second search of the same frame.
        ``expected``: the :class:`BallImage` of the tracked ball, when known: each candidate's
        centre is then the fit of that outline (:func:`fit_outline`). ``search``: the
        expected centre is only a rough guess (a track not confirmed yet): the fit starts
        from points around the blob's centre too (:meth:`_fit_centre`). ``later``: leave this
        frame's background update (every ``background_every`` frames) to
        :meth:`update_background`, for a caller that hands the detections on first.
        Returns a list of :class:`Detection` (best first); a frame that is not an image of the
        background's size raises ValueError.
        """
        cfg = self.config
        if (not isinstance(frame, np.ndarray) or frame.dtype != np.uint8 or frame.size == 0
                or not (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3))):
            raise ValueError('frame is not an 8-bit grey or BGR image')
        h, w = frame.shape[:2]
        if self.colourless is None and frame.ndim == 3:
            self.colourless = bool(np.array_equal(frame[:, :, 0], frame[:, :, 1])
                                   and np.array_equal(frame[:, :, 1], frame[:, :, 2]))
        if self.colourless and frame.ndim == 3:
            # Its three equal channels as one: as BGR the colour test refused every blob of
            # an orange ball (grey is no orange), and nothing was tracked without a word.
            frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        if self.background is None:
            gray = _grey(frame)
            self.background = gray.astype(np.float32)
            self._bg8 = gray.copy()
            if frame.ndim == 3:
                self._bg_colour = frame.astype(np.float32)
                self._bg_colour8 = frame.copy()
            self.level = self._exposure_level()
            return []
        if (h, w) != self.background.shape:
            raise ValueError(f"frame size {w}x{h} differs from the camera's "
                             f'{self.background.shape[1]}x{self.background.shape[0]}')
        if update_background:
            self.update_background()            # one left by the last frame comes first
        self._count += 1
        update = update_background and self._count % cfg.background_every == 0
        if roi_centre is not None and np.all(np.isfinite(roi_centre)):
            half = cfg.roi_half_size
            x0 = int(min(max(roi_centre[0] - half, 0), w))
            y0 = int(min(max(roi_centre[1] - half, 0), h))
            x1, y1 = int(min(x0 + 2 * half, w)), int(min(y0 + 2 * half, h))
        else:
            x0, y0, x1, y1 = 0, 0, w, h
        found = []
        mask = window = None
        self.gain, self.gain_grid, self._gain_map = 1.0, None, None
        if x1 > x0 and y1 > y0:
            window = _grey(frame[y0:y1, x0:x1])
            self.gain, self.gain_grid = light_gains(frame, self._bg8)
            diff = cv2.absdiff(window, self._background8_patch(
                self.background, self._bg8, y0, y1, x0, x1))
            _, mask = cv2.threshold(diff, cfg.diff_threshold, 255, cv2.THRESH_BINARY)
            if self._bg_colour8 is not None and frame.ndim == 3:
                mask |= colour_only_blobs(
                    frame[y0:y1, x0:x1],
                    self._background8_patch(self._bg_colour, self._bg_colour8, y0, y1, x0, x1),
                    mask, cfg.colour_change_threshold, cfg.min_area)
            bx, by, bw, bh = cv2.boundingRect(mask)
            if bw > 0 and bh > 0:      # label only the part of the window that changed
                # A blob cut by the window's edge (not the image's) is not measured whole.
                cut = (x0 > 0 and bx == 0, y0 > 0 and by == 0,
                       x1 < w and bx + bw == x1 - x0, y1 < h and by + bh == y1 - y0)
                found = self._blobs(frame, diff[by:by + bh, bx:bx + bw],
                                    mask[by:by + bh, bx:bx + bw], x0 + bx, y0 + by, cut,
                                    expected, search)
        if update:
            self._pending = (frame, window, mask, x0, y0)
            if not later:
                self.update_background()
        return found

    def update_background(self):
        """The background update that :meth:`detect` (``later``) left pending, if any.

        It reads and writes the whole background (the grey and the colour one, float images:
        0.7 ms on a 640 x 480 frame on a camera thread, where they are not in the cache), and
        55 of the slowest 62 states of the camrate scene (1 %) came from frames that waited
        for it: perception_node's camera threads queue a frame's detections first, then
        update."""
        pending, self._pending = self._pending, None
        if pending is not None:
            self._update_background(*pending)

    def _blobs(self, frame, diff, mask, x0, y0, cut=(False, False, False, False),
               expected=None, search=False):
        """Candidates among the blobs of ``mask`` (a crop at x0, y0 of the frame); ``cut``
        says which crop edges (left, top, right, bottom) cut through the scene."""
        cfg = self.config
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        h, w = mask.shape
        fh, fw = frame.shape[:2]
        colour_frame = frame.ndim == 3
        with_colour = cfg.colour != 'any' and colour_frame
        known = with_colour and self._bg_colour is not None     # the background's colour
        out = []
        for i in range(1, n):
            area = stats[i, cv2.CC_STAT_AREA]
            if area < cfg.min_area or area > cfg.max_area:
                continue
            bx, by, bw, bh = (int(v) for v in stats[i, :4])
            if ((cut[0] and bx == 0) or (cut[1] and by == 0) or (cut[2] and bx + bw == w)
                    or (cut[3] and by + bh == h)):
                continue
            sub = (labels[by:by + bh, bx:bx + bw] == i).astype(np.uint8)
            # The blob's box and HIDDEN_MARGIN pixels around it, within the frame.
            ux, uy = x0 + bx, y0 + by
            ax, ay = max(ux - HIDDEN_MARGIN, 0), max(uy - HIDDEN_MARGIN, 0)
            ex, ey = min(ux + bw + HIDDEN_MARGIN, fw), min(uy + bh + HIDDEN_MARGIN, fh)
            patch = np.ascontiguousarray(frame[ay:ey, ax:ex])
            background = (self._background_patch(self._bg_colour, ay, ey, ax, ex) if known
                          else _NO_BACKGROUND)
            m = _blob_measures(sub, np.ascontiguousarray(diff[by:by + bh, bx:bx + bw]),
                               _grey(patch), patch if colour_frame else _NO_PATCH,
                               background, ux - ax, uy - ay, float(cfg.diff_threshold),
                               with_colour, known)
            total, cu, cv, cxx, cyy, cxy, hidden = m[:7]
            if total <= 0.0:
                continue
            cu, cv = bx + cu, by + cv                 # difference-weighted centroid
            width = bright_width = _width_from_moments(cxx, cyy, cxy)
            if width > cfg.max_width:
                continue
            bright_length = _width_from_moments(cxx, cyy, cxy, longest=True)
            sure = True
            if with_colour:
                # The colour of the lit half of the blob: the shaded half and the outline
                # take the background's colour (JPEG's halved chroma resolution spreads it).
                # As the camera would show it exposed to WHITE_LEVEL (self.level).
                seen = m[7:10] / np.asarray(cfg.white_bgr)
                scale = 1.0 / min(self.level * self._gain_at(x0 + cu, y0 + cv), 1.0)
                colour = seen * scale
                change = colour - m[10:13] / np.asarray(cfg.white_bgr) * scale if known else None
                if not colour_matches(colour, cfg.colour, change):
                    if not colour_possible(colour, cfg.colour, change):
                        self.colour_refused += 1
                        self.refused_colours.append(seen)
                        continue
                    sure = False
            if self._bg_colour is not None and colour_frame:
                silhouette = self._silhouette_centre(frame, sub, ux, uy)
                if silhouette is not None:
                    cu, cv, width = silhouette[0] - x0, silhouette[1] - y0, silhouette[2]
            fitted = None
            blob_u, blob_v = float(cu + x0), float(cv + y0)
            if expected is not None:
                fitted = self._fit_centre(frame, blob_u, blob_v, expected, search)
            u, v = (blob_u, blob_v) if fitted is None else fitted
            out.append(Detection(float(u), float(v), float(area), float(width),
                                 float(total / area), float(hidden), fitted is not None,
                                 blob_u, blob_v, sure, bright_width, bright_length))
        out.sort(key=lambda d: (not d.colour_sure, -d.strength * d.area))
        return out[:cfg.max_candidates]

    def _exposure_level(self):
        """:func:`exposure_level` of the background."""
        colour = None if self._bg_colour is None or self.colourless else self._bg_colour
        return exposure_level(self._bg8, colour, self.config.white_bgr)

    def _gains(self):
        """The light's gain at each pixel of the frame being searched (float32, H x W): its
        parts' gains (:attr:`gain_grid`) interpolated between their centres."""
        if self._gain_map is None:
            h, w = self.background.shape
            self._gain_map = cv2.resize(self.gain_grid, (w, h), interpolation=cv2.INTER_LINEAR)
        return self._gain_map

    def _gain_at(self, u, v):
        """The light's gain at pixel (u, v) of the frame being searched."""
        if self.gain_grid is None:
            return self.gain
        h, w = self.background.shape
        return float(self._gains()[min(max(int(v), 0), h - 1), min(max(int(u), 0), w - 1)])

    def _background_patch(self, background, y0, y1, x0, x1):
        """``background`` (the grey or the colour one) on rows y0:y1 and columns x0:x1, times
        the light's gain in the frame being searched (:func:`light_gains`: its parts' where
        they differ), contiguous."""
        patch = background[y0:y1, x0:x1]
        if self.gain_grid is not None:
            gains = self._gains()[y0:y1, x0:x1]
            return patch * (gains[:, :, None] if patch.ndim == 3 else gains)
        if self.gain != 1.0:
            return patch * np.float32(self.gain)
        return np.ascontiguousarray(patch)

    def _background8_patch(self, background, rounded, y0, y1, x0, x1):
        """:meth:`_background_patch` rounded to uint8 (saturated); ``rounded``: the background
        so rounded, its patch as it is where the frame's gain is 1."""
        if self.gain_grid is not None:
            return cv2.convertScaleAbs(self._background_patch(background, y0, y1, x0, x1))
        if self.gain != 1.0:
            return cv2.convertScaleAbs(background[y0:y1, x0:x1], alpha=self.gain)
        return rounded[y0:y1, x0:x1]

    def _silhouette_centre(self, frame, sub, x0, y0):
        """Centre (u, v) and width, pixels, of the silhouette of the ball whose bright blob is
        ``sub`` at (x0, y0): every pixel near it whose colour differs from the colour
        background by more than ``silhouette_threshold`` in some channel and is not a shadow
        (darker in all three channels), connected to the blob. The silhouette's centroid does
        not lean toward the lit side as a difference-weighted centroid does. None when the
        silhouette has no weight."""
        h, w = frame.shape[:2]
        bh, bw = sub.shape
        m = max(bw, bh) + 2           # the unlit part may reach a diameter beyond the lit one
        ax, ay = max(x0 - m, 0), max(y0 - m, 0)
        bx, by = min(x0 + bw + m, w), min(y0 + bh + m, h)
        # Contiguous arrays and Python ints: the kernel's one compiled signature (warm_up).
        moments = _silhouette_moments(
            np.ascontiguousarray(frame[ay:by, ax:bx]),
            self._background_patch(self._bg_colour, ay, by, ax, bx), np.ascontiguousarray(sub),
            int(x0 - ax), int(y0 - ay), float(self.config.silhouette_threshold))
        if moments is None:
            return None
        cu, cv, cxx, cyy, cxy = moments
        return ax + cu, ay + cv, _width_from_moments(cxx, cyy, cxy)

    def _fit_centre(self, frame, u, v, ball, search=False):
        """:func:`fit_outline` for a candidate whose first centre is (u, v): (u, v) or None.

        The fit starts from (u, v) and, when it ends more than half a pixel from the
        predicted centre, from there too. With ``search`` (the prediction is rough), also
        from the 4 points :data:`SEARCH_STEP` radii around (u, v) along the image axes
        (:data:`SEARCH_OFFSETS`): a blob's centre leans toward the lit side by up to a third
        of a radius, and from there the fit can stop in a minimum of its own.

        With ``light_from_above``, a fit lit from below (:meth:`OutlineFit.fit`) loses to any
        that is not, whatever their costs, and a first fit lit from below is tried again from
        the predicted centre: on a ball of 2-3 px whose shaded half is as dark as the
        background, a centre up to a radius too high, lit from below, fits about as well."""
        h, w = frame.shape[:2]
        reach = _outline_extent(ball.outline)[0] + 0.5 * math.hypot(*ball.blur)
        half = int(np.ceil(reach + 2.0))
        ax, ay = int(round(u)) - half, int(round(v)) - half
        bx, by = ax + 2 * half + 1, ay + 2 * half + 1
        if ax < 0 or ay < 0 or bx > w or by > h:
            return None
        patch = np.ascontiguousarray(frame[ay:by, ax:bx])
        # The pixels the ball may cover for a centre within a pixel of (u, v), but a shadow's.
        shadows = self._bg_colour is not None and patch.ndim == 3
        obs, background, xs, ys = _usable_pixels(
            _grey(patch), patch if shadows else _NO_PATCH,
            self._background_patch(self._bg_colour, ay, by, ax, bx) if shadows
            else _NO_BACKGROUND,
            self._background_patch(self.background, ay, by, ax, bx), float(u - ax), float(v - ay),
            float(reach + 1.5), shadows)
        gamma = self.config.response_gamma
        encoded = None
        if gamma != 1.0:          # back to light: an outline pixel mixes light, not values
            obs = 255.0 * (obs * (1.0 / 255.0)) ** gamma
            background = 255.0 * (background * (1.0 / 255.0)) ** gamma
            if self.config.encoded_blur > 0.0:
                whole = self._background_patch(self.background, ay, by, ax, bx).astype(float)
                encoded = (255.0 * (whole * (1.0 / 255.0)) ** gamma, gamma,
                           self.config.encoded_blur)
        fitter = OutlineFit(None, None, None, ball, curvature_weight=self.config.curvature_weight,
                            image_blur=self.config.image_blur,
                            pixels=(obs.astype(float), background.astype(float), xs, ys),
                            encoded=encoded, inside_huber=self.config.inside_huber)
        lit = self.config.light_from_above

        def better(fit, best):
            """Whether ``fit`` beats ``best``: not lit from below when ``best`` is (with
            light_from_above), else of lower cost."""
            if fit is None:
                return False
            if best is None:
                return True
            if lit and fit[2] != best[2]:
                return best[2]
            return fit[1] < best[1]

        # From the candidate's own centre; on a ball of a few pixels JPEG's blocks can leave
        # a second minimum a pixel or two away, so when that fit ends more than half a pixel
        # from the predicted centre (or lit from below), from there too, and the better fit.
        best = fitter.fit((u - ax, v - ay), refine=False)
        predicted = (ball.u - ax, ball.v - ay)
        if best is None or np.hypot(*(best[0] - predicted)) > 0.5 or (lit and best[2]):
            fit = fitter.fit(predicted, refine=False)
            if better(fit, best):
                best = fit
        if search:
            step = SEARCH_STEP * fitter.scale
            for du, dv in SEARCH_OFFSETS:
                fit = fitter.fit((u - ax + step * du, v - ay + step * dv), refine=False)
                if better(fit, best):
                    best = fit
        if best is not None:
            best = fitter.refine(best)
        if best is None:
            return None
        if self.fits is not None:
            self.fits.append((fitter, best[0]))
        return best[0][0] + ax, best[0][1] + ay

    def _update_background(self, frame, window, mask, x0, y0):
        """Exponential average of the frame into the background, except under blobs (``mask``,
        at x0, y0, grown by 2 pixels). ``window``: the grey of the part of the frame searched
        (at x0, y0; None: none), the frame's grey when it is all of it.

        OpenCV's masked average costs three times the plain one (0.35 against 0.13 ms a
        640 x 480 colour frame, on a camera thread every ``background_every`` frames): it runs
        on the box around the grown blobs only, the plain one on the rest of the frame."""
        whole = window is not None and window.shape == frame.shape[:2]
        gray = window if whole else _grey(frame)
        backgrounds = [(gray, self.background)]
        if self._bg_colour is not None and frame.ndim == 3:
            backgrounds.append((frame, self._bg_colour))
        rate = self.config.background_rate
        h, w = gray.shape
        bx = by = bw = bh = 0
        if mask is not None:
            grown = cv2.dilate(mask, _GROW_KERNEL)
            bx, by, bw, bh = cv2.boundingRect(grown)
        if bw == 0 or bh == 0:
            for image, background in backgrounds:
                cv2.accumulateWeighted(image, background, rate)
        else:
            keep = grown[by:by + bh, bx:bx + bw] ^ 255
            bx, by = bx + x0, by + y0
            rest = ((slice(0, by), slice(0, w)), (slice(by + bh, h), slice(0, w)),
                    (slice(by, by + bh), slice(0, bx)), (slice(by, by + bh), slice(bx + bw, w)))
            box = (slice(by, by + bh), slice(bx, bx + bw))
            for image, background in backgrounds:
                cv2.accumulateWeighted(image[box], background[box], rate, mask=keep)
                for part in rest:
                    if background[part].size:
                        cv2.accumulateWeighted(image[part], background[part], rate)
        self._bg8 = cv2.convertScaleAbs(self.background)
        if len(backgrounds) > 1:
            self._bg_colour8 = cv2.convertScaleAbs(self._bg_colour)
        self._updates += 1
        if self._updates % LEVEL_EVERY == 0:
            self.level = self._exposure_level()
