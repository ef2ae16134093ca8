"""Synthetic scenes: a 40 mm ball flying per tt_prediction's model, seen by calibrated cameras.

The frames are rendered through the rig's pinhole cameras with lens distortion, sensor noise,
motion blur over the exposure, a slow change of lighting and a distracting object (a
racket-sized, ball-coloured disc swinging at the robot's end, and a spare ball lying still on
the floor). Each frame's time is the middle of its exposure, the instant the detector's centroid
of the blurred ball refers to. The truth is the model's state (tt_prediction.integrate.rollout,
bounces included) at the frame times.

Public API (used by the tests and ``make demo``):

- :func:`make_rig` writes a 2-camera rig (rig.yaml + one camera_info YAML per camera).
  :func:`demo_rig` is that rig in memory; :func:`look_at_rig` any rig of cameras looking
  from an eye at a target (``bench/bench_other_rigs.py``'s).
- :func:`render_balls` yields ``(t, camera_index, frame)`` in time order and returns the truth.
- :func:`write_scene` writes the frames as video files (or PNG sequences) plus ``truth.csv``;
  :class:`CameraVideos` is its video writer (one MJPG file per camera).
"""

import csv
import os

import cv2
import numpy as np
from tt_prediction.ball import (
    HALF_LENGTH,
    HALF_WIDTH,
    NET_HALF_WIDTH,
    NET_HEIGHT,
    ModelParams,
    rollout,
)

from .camera import Camera, Rig, load_rig, look_at, save_camera_info, save_rig

BALL_COLOURS = {'white': (235, 238, 240), 'orange': (20, 120, 250)}
"""Ball colour (BGR, full light) by name."""
IMAGING = ('clean', 'hall')
"""The modes of :func:`render_balls`: the flat-lit ball, or what a hall's camera sees."""

# Two poses of the demo rig: behind and above the robot's end, and to the side of its half.
_POSES = (
    ((-3.3, 0.35, 1.45), (0.2, 0.0, 0.0)),
    ((-0.3, -2.9, 1.1), (-0.3, 0.0, 0.2)),
)


def make_rig(directory, width=640, height=480, fps=150.0, sources=None, time_offsets=None):
    """Write a 2-camera rig looking at the table to ``directory``; returns the rig file path.

    Camera 0 stands 1.9 m behind the robot's end line, 1.45 m above the surface, looking down
    the table; camera 1 stands 2.9 m to the side of the robot's half. Both have a 60 degree
    horizontal field of view and mild barrel distortion. ``sources`` defaults to the image
    topics ``/cam0/image_raw`` and ``/cam1/image_raw``; ``time_offsets`` (s) are written when
    given.
    """
    os.makedirs(directory, exist_ok=True)
    rig = demo_rig(width, height, fps, sources, time_offsets)
    for cam in rig.cameras:
        save_camera_info(os.path.join(directory, f'{cam.name}.yaml'), cam.name, cam.width,
                         cam.height, cam.K, cam.dist)
    path = os.path.join(directory, 'rig.yaml')
    save_rig(path, rig)
    rig.path = os.path.abspath(path)
    return path


def demo_rig(width=640, height=480, fps=150.0, sources=None, time_offsets=None):
    """The rig of :func:`make_rig` in memory (:class:`tt_perception.camera.Rig`)."""
    return look_at_rig(_POSES, 60.0, (-0.11, 0.04, 0.0005, -0.0003, 0.0), fps, width, height,
                       principal_offset=(3.0, -2.0), sources=sources,
                       time_offsets=time_offsets)


def look_at_rig(poses, fov_deg, dist, fps, width=640, height=480, principal_offset=(0.0, 0.0),
                sources=None, time_offsets=None):
    """A :class:`tt_perception.camera.Rig` of cameras ``cam0``, ``cam1``, ... at ``poses``
    (eye, target; table frame, m), each looking from its eye at its target with the image's
    up toward the table's +z, all with one lens: ``fov_deg`` horizontal field of view,
    plumb-bob distortion ``dist`` (5,), the principal point ``principal_offset`` (px) from
    the image's centre. ``sources`` default to the image topics ``/camN/image_raw``."""
    focal = 0.5 * width / np.tan(np.radians(0.5 * fov_deg))
    K = np.array([[focal, 0.0, 0.5 * width - 0.5 + principal_offset[0]],
                  [0.0, focal, 0.5 * height - 0.5 + principal_offset[1]],
                  [0.0, 0.0, 1.0]])
    dist = np.array(dist, dtype=float)
    cameras = []
    for i, (eye, target) in enumerate(poses):
        R, t = look_at(eye, target)
        source = sources[i] if sources else f'/cam{i}/image_raw'
        offset = time_offsets[i] if time_offsets is not None else None
        cameras.append(Camera(f'cam{i}', width, height, K, dist, R, t, source=source,
                              time_offset=offset))
    return Rig(cameras, float(fps))


def incoming_ball(speed=8.0, topspin_rps=0.0, sidespin_rps=0.0, y0=0.1, z0=0.3, x0=1.5,
                  target=(-0.7, -0.1), params=None):
    """A plausible initial state (9,) of a ball served from the opponent's side toward x < 0.

    The ball starts at (x0, y0, z0) with horizontal speed ``speed`` (m/s) toward ``target``
    (x, y) on the robot's half; its vertical velocity is solved (bisection on the model) so that
    it first bounces at ``target``. ``topspin_rps`` spins it about the horizontal axis across
    its path (positive: topspin), ``sidespin_rps`` about the vertical. Spin in rad/s.
    """
    params = params or ModelParams()
    p = np.array([x0, y0, z0], dtype=float)
    d = np.array([target[0] - x0, target[1] - y0, 0.0])
    d /= np.linalg.norm(d)
    across = np.cross(d, [0.0, 0.0, 1.0])    # to the ball's right
    w = 2 * np.pi * (topspin_rps * -across + sidespin_rps * np.array([0.0, 0.0, 1.0]))

    def first_bounce_x(vz):
        state = np.concatenate([p, speed * d + [0.0, 0.0, vz], w])
        events, _ = rollout(state, params, t_max=3.0, stop_at_net=False, max_bounces=1)
        return events[-1].state[0] if events[-1].kind == 'bounce' else -np.inf

    lo, hi = -2.0, 6.0
    for _ in range(50):                      # bounce x decreases as vz grows
        mid = 0.5 * (lo + hi)
        if first_bounce_x(mid) > target[0]:
            lo = mid
        else:
            hi = mid
    return np.concatenate([p, speed * d + [0.0, 0.0, 0.5 * (lo + hi)], w])


def _background(cam, rng):
    """A static scene image (BGR uint8) for one camera: floor, table with lines, net."""
    h, w = cam.height, cam.width
    yy, xx = np.mgrid[0:h, 0:w]
    floor = 55 + 12 * np.sin(xx / 37.0) * np.cos(yy / 23.0) + rng.normal(0, 3, (h, w))
    img = np.repeat(floor[:, :, None], 3, axis=2)
    img[:, :, 0] += 8
    img = np.clip(img, 0, 255).astype(np.uint8)

    def poly(points):
        px = cam.project(np.asarray(points, dtype=float))
        return np.round(px * 16).astype(np.int32)

    def edge(a, b, n=40):
        return np.linspace(a, b, n)

    L, W = HALF_LENGTH, HALF_WIDTH
    corners = [(-L, -W, 0), (L, -W, 0), (L, W, 0), (-L, W, 0)]
    if not np.all(cam.in_front(np.asarray(corners))):
        return img
    outline = np.vstack([edge(corners[i], corners[(i + 1) % 4]) for i in range(4)])
    cv2.fillPoly(img, [poly(outline)], (95, 60, 25), cv2.LINE_AA, shift=4)
    for a, b in ((corners[0], corners[1]), (corners[1], corners[2]),
                 (corners[2], corners[3]), (corners[3], corners[0]),
                 ((-L, 0, 0), (L, 0, 0))):
        cv2.polylines(img, [poly(edge(a, b))], False, (200, 200, 200), 2, cv2.LINE_AA, shift=4)
    net = [(0, -NET_HALF_WIDTH, 0), (0, NET_HALF_WIDTH, 0),
           (0, NET_HALF_WIDTH, NET_HEIGHT), (0, -NET_HALF_WIDTH, NET_HEIGHT)]
    net_outline = np.vstack([edge(net[i], net[(i + 1) % 4]) for i in range(4)])
    cv2.fillPoly(img, [poly(net_outline)], (45, 45, 50), cv2.LINE_AA, shift=4)
    # A spare ball lying still on the floor beside the table (static: not a flying ball).
    spare = cam.project([[-1.0, 1.1, -0.74]])[0]
    cv2.circle(img, tuple(np.round(spare * 16).astype(int)), 16 * 5, BALL_COLOURS['white'],
               -1, cv2.LINE_AA, shift=4)
    return img


def _ball_box(frame, centres, radius):
    """Pixel box (x0, y0, x1, y1) of ``frame`` holding discs of ``radius`` at ``centres``
    (n, 2), or None when it lies outside the image."""
    h, w = frame.shape[:2]
    lo = np.floor(centres.min(axis=0) - radius - 2).astype(int)
    hi = np.ceil(centres.max(axis=0) + radius + 2).astype(int)
    x0, y0 = max(lo[0], 0), max(lo[1], 0)
    x1, y1 = min(hi[0] + 1, w), min(hi[1] + 1, h)
    return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None


def _draw_ball(frame, centres, radius, colour, gain):
    """Blend a motion-blurred disc into ``frame``: mean coverage of discs at ``centres``."""
    box = _ball_box(frame, centres, radius)
    if box is None:
        return
    x0, y0, x1, y1 = box
    ys, xs = np.mgrid[y0:y1, x0:x1]
    cover = np.zeros(xs.shape)
    for cx, cy in centres:
        d = np.hypot(xs - cx, ys - cy)
        cover += np.clip(radius + 0.5 - d, 0.0, 1.0)
    cover = (cover / len(centres))[:, :, None]
    # Slight shading: the lit top of the ball is brighter than its underside.
    shade = 1.0 - 0.08 * np.clip((ys - centres[:, 1].mean()) / max(radius, 1.0), -1, 1)
    ball = np.asarray(colour, dtype=float) * gain * shade[:, :, None]
    patch = frame[y0:y1, x0:x1].astype(float)
    frame[y0:y1, x0:x1] = np.clip(patch * (1.0 - cover) + np.clip(ball, 0, 255) * cover,
                                  0, 255).astype(np.uint8)


def _draw_ball_lit(frame, centres, radius, colour, gain, R, light):
    """Blend a motion-blurred ball lit by a directional overhead light into ``frame``.

    Each pixel of the disc at each centre of ``centres`` (n, 2) gets the sphere's normal
    (camera frame: x right, y down, z forward; ``R`` rotates table to camera), Lambert shading
    ``ambient + diffuse * max(0, n . l)`` of the ball's ``colour`` and a Blinn-Phong specular
    highlight; ``light`` is a dict with ``direction`` (table frame, toward the light),
    ``ambient``, ``diffuse``, ``specular`` and ``shininess``. The pixel is the mean over the
    exposure of ball (where covered) and background.
    """
    box = _ball_box(frame, centres, radius)
    if box is None:
        return
    x0, y0, x1, y1 = box
    l_cam = R @ np.asarray(light['direction'], float)
    l_cam /= np.linalg.norm(l_cam)
    half = l_cam + np.array([0.0, 0.0, -1.0])       # toward the light and toward the camera
    half /= np.linalg.norm(half)
    ys, xs = np.mgrid[y0:y1, x0:x1] + 0.0
    patch = frame[y0:y1, x0:x1].astype(float)
    out = np.zeros_like(patch)
    colour = np.asarray(colour, float) * gain
    ss = 4                                          # 4 x 4 samples per pixel for the coverage
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    for cx, cy in centres:
        acc = np.zeros_like(patch)
        for oy in offs:
            for ox in offs:
                dx, dy = (xs + ox - cx) / radius, (ys + oy - cy) / radius
                rr = dx * dx + dy * dy
                inside = rr < 1.0
                nz = -np.sqrt(np.clip(1.0 - rr, 0.0, 1.0))
                lam = np.clip(dx * l_cam[0] + dy * l_cam[1] + nz * l_cam[2], 0.0, None)
                spec = np.clip(dx * half[0] + dy * half[1] + nz * half[2], 0.0, None)
                shade = (light['ambient'] + light['diffuse'] * lam)[:, :, None] * colour \
                    + (255.0 * gain * light['specular'] * spec ** light['shininess'])[:, :, None]
                acc += np.where(inside[:, :, None], np.clip(shade, 0, 255), patch)
        out += acc / ss ** 2
    frame[y0:y1, x0:x1] = np.clip(out / len(centres), 0, 255).astype(np.uint8)


HALL_LIGHT = {'direction': (0.15, 0.1, 1.0), 'ambient': 0.4, 'diffuse': 0.7,
              'specular': 0.35, 'shininess': 30.0}
"""The hall's light: mostly from above, a soft ambient from walls and floor (a fraction of
full light), a glossy highlight."""


def _shadow(frame, cam, ball, radius):
    """Darken ``frame`` under a ball at ``ball`` (3,): a soft contact shadow on the table top,
    darker and tighter the closer the ball is to the surface (overhead light)."""
    height = ball[2] - radius
    if height > 0.4 or abs(ball[0]) > HALF_LENGTH or abs(ball[1]) > HALF_WIDTH or height < -0.01:
        return
    spread = radius * (1.0 + 4.0 * max(height, 0.0))
    depth = 0.55 * np.exp(-max(height, 0.0) / 0.08)
    angles = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    ring = np.stack([ball[0] + 2.0 * spread * np.cos(angles),
                     ball[1] + 2.0 * spread * np.sin(angles), np.zeros_like(angles)], axis=1)
    if not np.all(cam.in_front(ring)):
        return
    px = cam.project(ring)
    lo = np.floor(px.min(axis=0)).astype(int) - 2
    hi = np.ceil(px.max(axis=0)).astype(int) + 3
    x0, y0 = max(lo[0], 0), max(lo[1], 0)
    x1, y1 = min(hi[0], frame.shape[1]), min(hi[1], frame.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    # Shadow density on the table: Gaussian of the distance to the foot of the ball.
    ys, xs = np.mgrid[y0:y1, x0:x1] + 0.0
    pts = cam.normalise(np.stack([xs.ravel(), ys.ravel()], axis=1))
    rays = np.column_stack([pts, np.ones(len(pts))]) @ cam.R       # table frame directions
    s = -cam.centre[2] / rays[:, 2]
    hit = cam.centre[None, :2] + s[:, None] * rays[:, :2]
    d2 = np.sum((hit - ball[None, :2]) ** 2, axis=1).reshape(xs.shape)
    dark = 1.0 - depth * np.exp(-0.5 * d2 / spread ** 2)
    frame[y0:y1, x0:x1] = np.clip(frame[y0:y1, x0:x1] * dark[:, :, None], 0, 255).astype(
        np.uint8)


def _vignetting(cam, strength=0.35):
    """Relative illumination (H, W) of a lens falling as cos^4 toward the corners."""
    ys, xs = np.mgrid[0:cam.height, 0:cam.width] + 0.0
    r2 = ((xs - cam.K[0, 2]) ** 2 + (ys - cam.K[1, 2]) ** 2) / cam.focal ** 2
    return (1.0 - strength) + strength / (1.0 + r2) ** 2


def render_balls(rig, states, launch_times, colour='white', duration=1.5, lead_in=0.2,
                 exposure=1.5e-3, noise=2.0, lighting=0.15, distractor=True,
                 time_offsets=None, params=None, drop=None, seed=0, imaging='clean'):
    """Render the balls of ``states`` (each (9,), table frame) launched at ``launch_times`` (s).

    With no balls the scene holds only the background and the distractor, from ``-lead_in`` to
    ``duration``. Returns ``(frames, truth)``: ``frames`` is an iterator of
    ``(t, camera_index, frame)`` in time order (``frame`` uint8 H x W x 3 BGR; ``t`` the middle
    of the exposure, s: camera k's frames are at ``n / fps + time_offsets[k]``); ``truth`` is a
    list, one dict per ball, with ``t`` (k,), ``state`` (k, 9) at camera 0's frame times while
    the ball is in play, and ``events`` (the rollout's bounces and stop).

    ``exposure`` (s) sets the motion blur, ``noise`` the pixel noise (grey levels, std),
    ``lighting`` the relative fall of illumination over the scene (a slow ramp),
    ``distractor`` adds a swinging ball-coloured disc of racket size, and ``drop``
    (``{camera_index: (t_from, t_to)}``) replaces that camera's frames in the interval by
    ``None`` (a camera that vanishes).

    ``imaging='hall'`` renders what a hall's camera sees instead of the clean flat-lit ball: a
    directional overhead light (:data:`HALL_LIGHT`) with Lambert shading and a specular
    highlight, a soft contact shadow on the table, cos^4 vignetting, sensor noise with a shot
    part (``noise`` grey levels at mid-grey) and JPEG compression at quality 30; pass
    ``exposure=2e-3`` for the issue's 2 ms blur.
    """
    if imaging not in IMAGING:
        raise ValueError(f"imaging must be 'clean' or 'hall', not {imaging!r}")
    hall = imaging == 'hall'
    params = params or ModelParams()
    rng = np.random.default_rng(seed)
    cams = rig.cameras
    fps = rig.fps
    offsets = np.zeros(len(cams)) if time_offsets is None else np.asarray(time_offsets, float)
    launch_times = np.asarray(launch_times, dtype=float)
    first, last = (launch_times.min(), launch_times.max()) if launch_times.size else (0.0, 0.0)
    t_begin = float(first) - lead_in
    t_end = float(last) + duration
    n_frames = int(np.floor((t_end - t_begin) * fps)) + 1
    frame_t = t_begin + np.arange(n_frames) / fps
    n_sub = 5
    sub = (np.arange(n_sub) - 0.5 * (n_sub - 1)) / max(n_sub - 1, 1) * exposure
    # Ball trajectories at every camera's sub-exposure instants, and truth at camera 0's frames.
    truth, tracks = [], []
    for state, t0 in zip(states, launch_times, strict=True):
        times = np.sort(np.concatenate([(frame_t[:, None] + o + sub[None, :]).ravel()
                                        for o in offsets] + [frame_t]))
        keep = times >= t0
        events, samples = rollout(np.asarray(state, dtype=float), params, t0=t0,
                                  t_max=t0 + duration, stop_at_net=True, max_bounces=2,
                                  sample_times=times[keep])
        tracks.append((times[keep], samples))
        cam0_t = frame_t + offsets[0]           # camera 0's exposure mid-times
        cam0_t = cam0_t[cam0_t >= t0]
        st = samples[np.searchsorted(times[keep], cam0_t)]
        ok = np.all(np.isfinite(st), axis=1) & (st[:, 2] > -0.5)
        truth.append({'t': cam0_t[ok], 'state': st[ok], 'events': events})
    backgrounds = [_background(cam, rng) for cam in cams]
    if hall:
        backgrounds = [(bg * _vignetting(cam)[:, :, None]).astype(np.uint8)
                       for bg, cam in zip(backgrounds, cams, strict=True)]
        noise_bank = None
    else:
        noise_bank = [[np.clip(bg + rng.normal(0, noise, bg.shape), 0, 255).astype(np.uint8)
                       for _ in range(6)] for bg in backgrounds]
    colour_bgr = BALL_COLOURS[colour] if isinstance(colour, str) else colour
    drop = drop or {}

    def ball_positions(t):
        """Positions (n_sub, 3) of each ball in flight over the exposure around t."""
        out = []
        for times, samples in tracks:
            q = t + sub
            i = np.searchsorted(times, q)
            if np.any(i >= len(times)) or np.any(np.abs(times[np.minimum(i, len(times) - 1)]
                                                         - q) > 1e-9):
                continue
            p = samples[i, :3]
            if np.all(np.isfinite(p)) and p[:, 2].min() > -0.7:
                out.append(p)
        return out

    def frames():
        events = sorted((frame_t[n] + offsets[k], k, n) for n in range(n_frames)
                        for k in range(len(cams)))
        for t, k, n in events:
            span = drop.get(k)
            if span is not None and span[0] <= t <= span[1]:
                yield t, k, None
                continue
            cam = cams[k]
            gain = 1.0 - lighting * (t - t_begin) / max(t_end - t_begin, 1e-9)
            if hall:
                frame = cv2.convertScaleAbs(backgrounds[k], alpha=gain)
            else:
                frame = cv2.convertScaleAbs(noise_bank[k][n % 6], alpha=gain)
            if distractor:
                swing = 0.35 * np.sin(2 * np.pi * 0.8 * (t - t_begin))
                centre3 = np.array([[-1.75, 0.45 + swing, 0.25 + 0.5 * abs(swing)]])
                if cam.in_front(centre3)[0]:
                    c = cam.project(centre3)[0]
                    r = cam.focal * 0.08 / cam.to_camera(centre3)[0, 2]
                    cv2.circle(frame, tuple(np.round(c * 16).astype(int)), int(r * 16),
                               tuple(int(g * gain) for g in colour_bgr), -1, cv2.LINE_AA,
                               shift=4)
            for p in ball_positions(t):
                if not np.all(cam.in_front(p)):
                    continue
                centres = cam.project(p)
                depth = cam.to_camera(p[n_sub // 2:n_sub // 2 + 1])[0, 2]
                radius = cam.focal * params.radius / depth
                if hall:
                    _shadow(frame, cam, p[n_sub // 2], params.radius)
                    _draw_ball_lit(frame, centres, radius, colour_bgr, gain, cam.R, HALL_LIGHT)
                else:
                    _draw_ball(frame, centres, radius, colour_bgr, gain)
            if hall:
                frame = _sensor(frame, noise, rng)
            yield t, k, frame

    return frames(), truth


def both_cameras_see(rig, truth, rendered_from=-np.inf):
    """Mask of camera 0's frames (truth['t']) in which the true ball lies in front of and
    inside both cameras' images, from ``rendered_from`` (s) on: synth draws a ball only in
    frames whose whole exposure follows its launch (the frame at the launch time, exposed from
    half an exposure before it, has no ball)."""
    p = truth['state'][:, :3]
    ok = truth['t'] >= rendered_from - 1e-9
    for cam in rig.cameras:
        uv = cam.project(p)
        ok &= cam.in_front(p) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) \
            & (uv[:, 1] < cam.height)
    return ok


def _sensor(frame, noise, rng):
    """A hall camera's sensor and codec: photon (shot) noise growing as the square root of the
    signal plus read noise, then JPEG at quality 30, as cheap USB cameras send (MJPG)."""
    signal = frame.astype(np.float32)
    sigma = noise * np.sqrt(0.5 + signal / 256.0)
    noisy = np.clip(signal + sigma * rng.standard_normal(frame.shape, dtype=np.float32), 0, 255)
    _, data = cv2.imencode('.jpg', noisy.astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 30])
    return cv2.imdecode(data, cv2.IMREAD_COLOR)


class CameraVideos:
    """Each camera's frames as a video in ``directory``: ``<camera name>.avi``, MJPG (what a
    USB camera sends) at the rig's fps and the camera's size, created at the camera's first
    frame. ``write(k, frame)`` returns the file's name; ``tee(frames)`` passes ``(t, k,
    frame)`` through, writing every frame that is not None. Close it (or use ``with``) to
    finish the files."""

    def __init__(self, directory, rig):
        self.directory = str(directory)
        self.rig = rig
        self._writers = {}

    def write(self, k, frame):
        cam = self.rig.cameras[k]
        name = f'{cam.name}.avi'
        if k not in self._writers:
            self._writers[k] = cv2.VideoWriter(os.path.join(self.directory, name),
                                               cv2.VideoWriter_fourcc(*'MJPG'), self.rig.fps,
                                               (cam.width, cam.height))
        self._writers[k].write(frame)
        return name

    def tee(self, frames):
        for t, k, frame in frames:
            if frame is not None:
                self.write(k, frame)
            yield t, k, frame

    def close(self):
        for writer in self._writers.values():
            writer.release()
        self._writers.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def write_scene(directory, rig_path, frames, truth, fmt='avi', time_offset=None):
    """Write rendered frames to one video (``fmt='avi'``, MJPG) or PNG sequence per camera.

    The rig file at ``rig_path`` is rewritten with each camera's source pointing at its file
    (relative), and ``truth.csv`` (columns ``ball,t,x,y,z,vx,vy,vz,wx,wy,wz``) is written next
    to it (``truth`` None: no truth.csv). ``time_offset`` (s), when given, is written as the
    second camera's known offset (0.0: synchronised cameras, nothing to estimate). Returns
    the rig path.
    """
    rig = load_rig(rig_path)
    if time_offset is not None:
        rig.cameras[1].time_offset = float(time_offset)
    os.makedirs(directory, exist_ok=True)
    counters = {}
    written = 0
    with CameraVideos(directory, rig) as videos:
        for _, k, frame in frames:
            if frame is None:
                continue
            written += 1
            cam = rig.cameras[k]
            if fmt == 'avi':
                cam.source = videos.write(k, frame)
            else:
                folder = os.path.join(directory, cam.name)
                os.makedirs(folder, exist_ok=True)
                n = counters.get(k, 0)
                cv2.imwrite(os.path.join(folder, f'{n:06d}.png'), frame)
                counters[k] = n + 1
                cam.source = f'{cam.name}/%06d.png'
    if not written:
        # The second write_scene of render_balls' frames (an iterator) wrote a rig naming
        # videos that were never written.
        raise ValueError('write_scene: no frame given (render_balls gives its frames as an '
                         'iterator, consumed once: list() them to write them twice)')
    out_rig = os.path.join(directory, 'rig.yaml')
    for cam in rig.cameras:
        cam.info_file = f'{cam.name}.yaml'
        save_camera_info(os.path.join(directory, cam.info_file), cam.name, cam.width,
                         cam.height, cam.K, cam.dist)
    save_rig(out_rig, rig)
    if truth is None:
        return out_rig
    with open(os.path.join(directory, 'truth.csv'), 'w', newline='', encoding='utf-8') as f:
        w = csv.writer(f)
        w.writerow(['ball', 't', 'x', 'y', 'z', 'vx', 'vy', 'vz', 'wx', 'wy', 'wz'])
        for i, tr in enumerate(truth):
            for t, s in zip(tr['t'], tr['state'], strict=True):
                w.writerow([i, f'{t:.6f}'] + [f'{v:.6f}' for v in s])
    return out_rig
