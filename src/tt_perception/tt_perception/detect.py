"""Ball detection in one camera's frames: motion against a background model, then colour and
size, with a sub-pixel centre.

A pixel is a candidate when its grey level differs from the running background by more than
``diff_threshold``; 8-connected candidate pixels form blobs. A blob is kept when its area lies
within [min_area, max_area] pixels, its mean colour matches the ball's (white: the three
channels close and bright; orange: red well above blue), and its width (twice the square root
of the smaller eigenvalue of its second moments, the diameter of a disc whatever the motion
blur along the path) is within range. The centre is the difference-weighted centroid, which for
a motion-blurred disc is the centre at mid-exposure. When the caller knows where the ball
should be (the tracker's prediction) only a region of interest around it is searched; a blob
cut by the window's edge is not measured (a ball merging with a larger object there would
give a biased centre).

The background follows slow changes of lighting (exponential average, ``background_rate`` per
update, one update every ``background_every`` frames) except under the blobs found, so a ball
that hovers does not fade into it.
"""

import dataclasses

import cv2
import numpy as np


@dataclasses.dataclass
class DetectorConfig:
    """Thresholds of :class:`BallDetector` (pixels, grey levels)."""

    diff_threshold: float = 22.0
    """Minimum grey-level change against the background for a ball pixel."""
    min_area: int = 4
    """Smallest blob area, pixels."""
    max_area: int = 900
    """Largest blob area, pixels (a near, motion-blurred ball)."""
    max_width: float = 30.0
    """Largest blob width across its motion (ball diameter), pixels."""
    colour: str = 'any'
    """Ball colour: 'white', 'orange' or 'any'."""
    background_rate: float = 0.1
    """Weight of a new frame in the running background (per update)."""
    background_every: int = 3
    """Frames between two updates of the background."""
    roi_half_size: int = 40
    """Half size of the search window around a predicted position, pixels."""
    max_candidates: int = 4
    """Most blobs returned per frame (the largest differences first)."""
    silhouette_threshold: float = 14.0
    """Smallest colour change (largest over B, G, R against the colour background) of a pixel
    of the ball's silhouette, grey levels: low enough to keep its shaded underside."""


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


def colour_matches(bgr, colour, change=None):
    """True when the mean colour ``bgr`` (3,) is that of a ``colour`` ball ('white', 'orange',
    'any'). ``change`` (3,), the colour minus the background's there, when known: an orange
    ball small enough for JPEG's halved chroma resolution to mix the background into it is
    still recognised by the red it adds over the blue."""
    b, g, r = (float(c) for c in bgr)
    if colour == 'white':
        return min(b, g, r) > 0.72 * max(b, g, r) and max(b, g, r) > 90.0
    if colour == 'orange':
        if r > 90.0 and r > 1.6 * b + 20.0 and r > g:
            return True
        if change is None:
            return False
        db, dg, dr = (float(c) for c in change)
        return dr > 30.0 and dr > 1.6 * max(db, 0.0) + 10.0 and dr > dg
    return True


def _width_from_moments(cxx, cyy, cxy):
    """Width across the motion blur (the ball's diameter), pixels, from the central second
    moments of a blob's pixels (each pixel adds 1/12 of its own): a disc of radius r has
    variance r^2 / 4 along any axis, and blur only lengthens the other axis."""
    small = 0.5 * (cxx + cyy) - np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy ** 2)
    return 4.0 * np.sqrt(max(small, 0.0) + 1.0 / 12.0)


_KERNEL3 = np.ones((3, 3), np.uint8)


def _grey(image):
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


class BallDetector:
    """Detector of one camera (it keeps that camera's background)."""

    def __init__(self, config=None):
        self.config = config or DetectorConfig()
        self.background = None
        self._bg8 = None
        self._bg_colour = None
        self._count = 0

    def detect(self, frame, roi_centre=None, update_background=True):
        """Ball candidates in ``frame`` (H x W x 3 BGR or H x W grey uint8).

        ``roi_centre`` (u, v): search only the window of ``roi_half_size`` around it.
        ``update_background``: False for a second search of the same frame.
        Returns a list of :class:`Detection` (best first); a frame that is not an image of the
        background's size raises ValueError.
        """
        cfg = self.config
        if (not isinstance(frame, np.ndarray) or frame.dtype != np.uint8 or frame.size == 0
                or not (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3))):
            raise ValueError('frame is not an 8-bit grey or BGR image')
        h, w = frame.shape[:2]
        if self.background is None:
            gray = _grey(frame)
            self.background = gray.astype(np.float32)
            self._bg8 = gray.copy()
            if frame.ndim == 3:
                self._bg_colour = frame.astype(np.float32)
            return []
        if (h, w) != self.background.shape:
            raise ValueError(f"frame size {w}x{h} differs from the camera's "
                             f'{self.background.shape[1]}x{self.background.shape[0]}')
        self._count += 1
        update = update_background and self._count % cfg.background_every == 0
        if roi_centre is not None and np.all(np.isfinite(roi_centre)):
            half = cfg.roi_half_size
            x0 = int(min(max(roi_centre[0] - half, 0), w))
            y0 = int(min(max(roi_centre[1] - half, 0), h))
            x1, y1 = int(min(x0 + 2 * half, w)), int(min(y0 + 2 * half, h))
        else:
            x0, y0, x1, y1 = 0, 0, w, h
        gray = _grey(frame) if update else None
        found = []
        mask = None
        if x1 > x0 and y1 > y0:
            window = gray[y0:y1, x0:x1] if update else _grey(frame[y0:y1, x0:x1])
            diff = cv2.absdiff(window, self._bg8[y0:y1, x0:x1])
            _, mask = cv2.threshold(diff, cfg.diff_threshold, 255, cv2.THRESH_BINARY)
            bx, by, bw, bh = cv2.boundingRect(mask)
            if bw > 0 and bh > 0:      # label only the part of the window that changed
                # A blob cut by the window's edge (not the image's) is not measured whole.
                cut = (x0 > 0 and bx == 0, y0 > 0 and by == 0,
                       x1 < w and bx + bw == x1 - x0, y1 < h and by + bh == y1 - y0)
                found = self._blobs(frame, diff[by:by + bh, bx:bx + bw],
                                    mask[by:by + bh, bx:bx + bw], x0 + bx, y0 + by, cut)
        if update:
            self._update_background(gray, mask, x0, y0, frame)
        return found

    def _blobs(self, frame, diff, mask, x0, y0, cut=(False, False, False, False)):
        """Candidates among the blobs of ``mask`` (a crop at x0, y0 of the frame); ``cut``
        says which crop edges (left, top, right, bottom) cut through the scene."""
        cfg = self.config
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        h, w = mask.shape
        out = []
        for i in range(1, n):
            area = stats[i, cv2.CC_STAT_AREA]
            if area < cfg.min_area or area > cfg.max_area:
                continue
            bx, by, bw, bh = stats[i, :4]
            if ((cut[0] and bx == 0) or (cut[1] and by == 0) or (cut[2] and bx + bw == w)
                    or (cut[3] and by + bh == h)):
                continue
            sub = (labels[by:by + bh, bx:bx + bw] == i).astype(np.uint8)
            weighted = cv2.moments(cv2.multiply(diff[by:by + bh, bx:bx + bw], sub))
            total = weighted['m00']
            if total <= 0.0:
                continue
            cu = bx + weighted['m10'] / total       # difference-weighted centroid
            cv = by + weighted['m01'] / total
            shape = cv2.moments(sub, binaryImage=True)
            width = _width_from_moments(shape['mu20'] / area, shape['mu02'] / area,
                                        shape['mu11'] / area)
            if width > cfg.max_width:
                continue
            if cfg.colour != 'any' and frame.ndim == 3:
                # The colour of the lit half of the blob: the shaded half and the outline
                # take the background's colour (JPEG's halved chroma resolution spreads it).
                patch = frame[y0 + by:y0 + by + bh, x0 + bx:x0 + bx + bw]
                grey = _grey(patch)
                lit = ((sub > 0) & (grey >= np.median(grey[sub > 0]))).astype(np.uint8)
                colour = cv2.mean(patch, mask=lit)[:3]
                change = None
                if self._bg_colour is not None:
                    bg = self._bg_colour[y0 + by:y0 + by + bh, x0 + bx:x0 + bx + bw]
                    change = np.asarray(colour) - cv2.mean(bg, mask=lit)[:3]
                if not colour_matches(colour, cfg.colour, change):
                    continue
            if self._bg_colour is not None and frame.ndim == 3:
                cu, cv, width = self._silhouette_centre(frame, sub, x0 + bx, y0 + by)
                cu, cv = cu - x0, cv - y0
            out.append(Detection(float(cu + x0), float(cv + y0), float(area), float(width),
                                 float(total / area),
                                 self._hidden(frame, sub, x0 + bx, y0 + by)))
        out.sort(key=lambda d: -d.strength * d.area)
        return out[:cfg.max_candidates]

    def _silhouette_centre(self, frame, sub, x0, y0):
        """Centre (u, v) and width, pixels, of the silhouette of the ball whose bright blob is
        ``sub`` at (x0, y0): every pixel near it whose colour differs from the colour
        background by more than ``silhouette_threshold`` in some channel and is not a shadow
        (darker in all three channels), connected to the blob. The silhouette's centroid does
        not lean toward the lit side as a difference-weighted centroid does."""
        h, w = frame.shape[:2]
        bh, bw = sub.shape
        m = max(bw, bh) + 2           # the unlit part may reach a diameter beyond the lit one
        ax, ay = max(x0 - m, 0), max(y0 - m, 0)
        bx, by = min(x0 + bw + m, w), min(y0 + bh + m, h)
        img = frame[ay:by, ax:bx].astype(np.float32)
        bg = self._bg_colour[ay:by, ax:bx]
        change = img - bg
        size = np.abs(change).max(axis=2)
        sil = ((size > self.config.silhouette_threshold)
               & (change.max(axis=2) >= 0.0)).astype(np.uint8)    # not darker in all three
        seed = np.zeros_like(sil)
        seed[y0 - ay:y0 - ay + bh, x0 - ax:x0 - ax + bw] = sub
        sil |= seed
        _, labels = cv2.connectedComponents(sil, connectivity=8)
        keep = np.unique(labels[(seed > 0) & (labels > 0)])
        region = (labels == keep[0]) if len(keep) == 1 else np.isin(labels, keep)
        # Coverage: full inside the silhouette, the shaded side included; on its outline
        # (anti-aliased, blurred) the pixel's change over that of the ball's pixels next to it
        # (a mixed pixel changes in proportion to the part the ball covers, lit or shaded).
        region = region.astype(np.uint8)
        interior = cv2.erode(region, _KERNEL3, borderType=cv2.BORDER_REPLICATE)
        inner = interior.astype(np.float32)
        near_sum = cv2.boxFilter(size * inner, -1, (5, 5), normalize=False)
        near_n = cv2.boxFilter(inner, -1, (5, 5), normalize=False)
        outline = (region > 0) & (interior == 0)
        cover = inner
        if outline.any():
            local = near_sum[outline]
            n_near = near_n[outline]
            fallback = float(np.median(size[seed > 0]))
            local = np.where(n_near > 0, local / np.maximum(n_near, 1e-6), fallback)
            cover[outline] = np.clip(size[outline] / np.maximum(local, 1e-6), 0.0, 1.0)
        mom = cv2.moments(cover)
        total = mom['m00']
        cu, cv = mom['m10'] / total, mom['m01'] / total
        return (ax + cu, ay + cv,
                _width_from_moments(mom['mu20'] / total, mom['mu02'] / total, mom['mu11'] / total))

    def _hidden(self, frame, sub, x0, y0):
        """Fraction of the pixels around a blob (``sub`` at x0, y0) as bright as the ball: there
        the background looks like the ball, so the blob may have lost part of it."""
        h, w = frame.shape[:2]
        bh, bw = sub.shape
        ax, ay = max(x0 - 2, 0), max(y0 - 2, 0)
        bx, by = min(x0 + bw + 2, w), min(y0 + bh + 2, h)
        grey = _grey(frame[ay:by, ax:bx])
        inside = np.zeros(grey.shape, np.uint8)
        inside[y0 - ay:y0 - ay + bh, x0 - ax:x0 - ax + bw] = sub
        ring = cv2.dilate(inside, np.ones((3, 3), np.uint8)) - inside
        n_ring = cv2.countNonZero(ring)
        if n_ring == 0:
            return 0.0
        ball = cv2.mean(grey, mask=inside)[0]
        alike = cv2.absdiff(grey, np.full_like(grey, int(round(ball)))) < \
            self.config.diff_threshold
        return float(np.count_nonzero(alike & (ring > 0)) / n_ring)

    def _update_background(self, gray, mask, x0, y0, frame=None):
        """Exponential average of the frame into the background, except under blobs."""
        keep = None
        if mask is not None and mask.any():
            keep = np.full(gray.shape, 255, np.uint8)
            h, w = mask.shape
            keep[y0:y0 + h, x0:x0 + w] = cv2.dilate(mask, np.ones((5, 5), np.uint8)) ^ 255
        cv2.accumulateWeighted(gray, self.background, self.config.background_rate, mask=keep)
        if self._bg_colour is not None and frame.ndim == 3:
            cv2.accumulateWeighted(frame, self._bg_colour, self.config.background_rate,
                                   mask=keep)
        self._bg8 = cv2.convertScaleAbs(self.background)
