"""The independent scene renderer (independent_scene.py) against the physics it must obey,
without tt's perception: flight and bounce, ray-cast geometry, shadows, sensor."""

import dataclasses

import independent_scene as scene
import numpy as np
import pytest
from tt_perception.camera import Rig

from tt_perception import synth


def energy(states):
    """Mechanical energy per unit mass (J/kg) of states (n, 9)."""
    return 0.5 * np.sum(states[:, 3:6] ** 2, axis=1) + scene.GRAVITY * states[:, 2]


def test_flight_without_air_conserves_energy_and_is_a_parabola():
    s0 = np.array([1.4, 0.2, 0.35, -7.0, -0.5, 1.2, 30.0, -200.0, 50.0])
    f = scene.simulate(s0, 0.0, 0.12, drag=False, magnus=False)
    t = np.linspace(0.0, 0.12, 50)
    st = f.state(t)
    assert not f.bounces
    e = energy(st)
    assert np.ptp(e) / abs(e[0]) < 1e-10
    parabola = s0[:3] + np.outer(t, s0[3:6]) - 0.5 * scene.GRAVITY * np.outer(t * t, [0, 0, 1])
    assert np.abs(st[:, :3] - parabola).max() < 1e-9
    assert np.all(st[:, 6:] == s0[6:])            # spin constant in flight


def test_drag_and_magnus_in_the_trajectory():
    """The integrated velocity's rate of change is the force law's acceleration."""
    s0 = scene.serve(8.0, 40.0, 10.0)
    f = scene.simulate(s0, 0.0, 0.2)
    h = 1e-5
    for t in (0.05, 0.15):
        a_num = (f.state([t + h])[0, 3:6] - f.state([t - h])[0, 3:6]) / (2 * h)
        s = f.state([t])[0]
        assert np.allclose(a_num, scene.acceleration(s[3:6], s[6:]), atol=1e-5)
    # Topspin pulls the ball down: it lands shorter than a spinless one.
    plain = scene.simulate(np.concatenate([s0[:6], np.zeros(3)]), 0.0, 1.0, max_bounces=1)
    spun = scene.simulate(s0, 0.0, 1.0, max_bounces=1)
    assert spun.bounces[0][1][0] > plain.bounces[0][1][0]


def test_serve_bounces_at_the_target_at_contact_height():
    s0 = scene.serve(8.0, 40.0, 10.0, target=(-0.7, -0.1))
    f = scene.simulate(s0, 0.0, 0.8)
    t_b, before, after = f.bounces[0]
    assert abs(before[2] - scene.RADIUS) < 1e-9
    assert abs(before[0] + 0.7) < 1e-8 and before[0] < 0.0      # on the robot's half
    st = f.state(np.linspace(0.0, 0.8, 400))
    over = (np.abs(st[:, 0]) <= scene.TABLE_HALF_LENGTH) \
        & (np.abs(st[:, 1]) <= scene.TABLE_HALF_WIDTH)
    assert np.all(st[over, 2] > scene.RADIUS - 1e-9)               # never into the table
    assert st[-1, 0] < -scene.TABLE_HALF_LENGTH and st[-1, 2] < 0.0  # past the end, falling
    assert f.state([t_b + 0.05])[0, 2] > scene.RADIUS                # and flies on
    assert np.linalg.norm(s0[3:5]) == pytest.approx(8.0)


@pytest.mark.parametrize('state', [
    [0, 0, scene.RADIUS, 6.0, 0.5, -3.0, 20.0, -300.0, 40.0],      # topspin: rolls off
    [0, 0, scene.RADIUS, 6.0, 0.0, -3.0, 0.0, 500.0, 0.0],         # strong backspin: slides
    [0, 0, scene.RADIUS, 2.0, 1.0, -4.0, 0.0, 0.0, 0.0],           # no spin
])
def test_bounce_conserves_angular_momentum_about_the_contact_point(state):
    """The impulse acts at the contact point: the angular momentum about that point is kept;
    the normal velocity is reversed times e; the contact point ends rolling or still slides
    the same way, slower, with the friction impulse at its Coulomb limit."""
    before = np.asarray(state, dtype=float)
    after = scene.bounce(before)
    r = np.array([0.0, 0.0, scene.RADIUS])                 # contact -> centre
    inertia = 2.0 / 3.0 * scene.MASS * scene.RADIUS ** 2

    def momentum(s):
        return scene.MASS * np.cross(r, s[3:6]) + inertia * s[6:]

    assert np.allclose(momentum(before), momentum(after), atol=1e-12)
    assert after[5] == pytest.approx(-scene.RESTITUTION * before[5])

    def slip(s):
        return (s[3:6] + np.cross(s[6:], -r))[:2]

    s0, s1 = slip(before), slip(after)
    impulse = scene.MASS * np.linalg.norm(after[3:5] - before[3:5])
    limit = scene.FRICTION * scene.MASS * (1 + scene.RESTITUTION) * abs(before[5])
    assert impulse <= limit + 1e-12
    if np.linalg.norm(s1) > 1e-9:
        assert s1 @ s0 > 0 and impulse == pytest.approx(limit)
    else:
        assert impulse < limit


@pytest.fixture(scope='module')
def rigs():
    return {size: synth.demo_rig(*size) for size in ((640, 480), (1280, 720))}


def test_pixel_rays_reproject_to_their_pixels(rigs):
    rng = np.random.default_rng(1)
    for rig in rigs.values():
        for cam in rig.cameras:
            uv = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (200, 2))
            d = scene.pixel_rays(cam, uv)
            X = scene.camera_centre(cam) + 2.5 * d
            assert np.abs(cam.project(X) - uv).max() < 1e-6


BALL_SPOTS = [(-0.6, -0.1, 0.15), (0.5, 0.3, 0.25), (-1.2, 0.5, 0.1), (1.0, -0.5, 0.3)]


@pytest.mark.parametrize('size', [(640, 480), (1280, 720)])
def test_ball_image_centroid_and_diameter(rigs, size):
    """A still, flat-lit ball: the centroid of its ray-cast coverage is the camera's
    projection of its centre (within 0.05 px), its area that of a disc of diameter
    2 f r / depth (within 3 %; the lens's distortion changes it off axis)."""
    rig = rigs[size]
    renderer = scene.Renderer(rig, flat=True, time_samples=1)
    worst = 0.0
    for spot in BALL_SPOTS:
        for k, cam in enumerate(rig.cameras):
            ball = scene.Sphere(np.array([spot]), scene.RADIUS, scene.ball_material('white'))
            (x0, y0, _, _), cover, _ = renderer.coverage(k, ball)
            ys, xs = np.mgrid[0:cover.shape[0], 0:cover.shape[1]]
            area = cover.sum()
            centroid = np.array([(xs * cover).sum(), (ys * cover).sum()]) / area + (x0, y0)
            err = np.linalg.norm(centroid - cam.project(np.array([spot]))[0])
            worst = max(worst, err)
            depth = cam.to_camera(np.array([spot]))[0, 2]
            diameter = 2.0 * np.sqrt(area / np.pi)
            assert diameter == pytest.approx(2.0 * cam.focal * scene.RADIUS / depth, rel=0.03)
    assert worst < 0.05


def test_motion_blur_spreads_the_ball_along_its_path(rigs):
    """Over the exposure the coverage is the mean of the instants': its centroid is the
    mean of the projected centres and its extent along the path grows by the path's."""
    rig = rigs[(640, 480)]
    renderer = scene.Renderer(rig, flat=True, time_samples=8)
    times = renderer.sample_times(0.0)
    path = np.array([-0.6, -0.1, 0.15]) + np.outer(times, [-8.0, 0.0, 0.0])
    ball = scene.Sphere(path, scene.RADIUS, scene.ball_material('white'))
    (x0, y0, _, _), cover, _ = renderer.coverage(1, ball)
    ys, xs = np.mgrid[0:cover.shape[0], 0:cover.shape[1]]
    centroid = np.array([(xs * cover).sum(), (ys * cover).sum()]) / cover.sum() + (x0, y0)
    assert np.linalg.norm(centroid - rig.cameras[1].project(path).mean(axis=0)) < 0.05
    assert cover.max() <= 1.0
    cols = np.nonzero(cover.sum(axis=0) > 0)[0]
    span = rig.cameras[1].project(path[[0, -1]])
    assert cols[-1] - cols[0] + 1 >= abs(span[1, 0] - span[0, 0]) + 7


def test_shadow_lies_under_the_ball_darker_and_sharper_when_lower(rigs):
    renderer = scene.Renderer(rigs[(640, 480)])
    foot = np.array([-0.6, 0.2])
    g = np.linspace(-0.3, 0.3, 121)
    gx, gy = np.meshgrid(foot[0] + g, foot[1] + g)
    P = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    N = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    result = {}
    for height in (0.03, 0.1, 0.3):
        centre = np.array([[foot[0], foot[1], scene.RADIUS + height]])
        dark = 1.0 - renderer.shadow_factor(P, N, centre).mean(axis=1)
        w = dark / dark.sum()
        mean = w @ P[:, :2]
        spread = np.sqrt(w @ np.sum((P[:, :2] - mean) ** 2, axis=1))
        result[height] = (dark.max(), np.linalg.norm(mean - foot), spread)
    for height, (_, offset, _) in result.items():
        assert offset < 0.01 + 0.25 * height        # under the ball (lights spread around)
    depth = [result[h][0] for h in (0.03, 0.1, 0.3)]
    spread = [result[h][2] for h in (0.03, 0.1, 0.3)]
    assert depth[0] > depth[1] > depth[2] > 0.0
    assert depth[0] > 0.3          # one lamp of three fully hidden, ambient not
    assert spread[0] < spread[1] < spread[2]
    # No shadow far from the ball, nor from a ball below the plane of the points.
    far = np.array([[foot[0] + 1.0, foot[1], 0.0]])
    assert renderer.shadow_factor(far, N[:1], np.array([[*foot, 0.1]]))[0] == \
        pytest.approx(1.0)


def test_rendered_frame_darkens_the_table_under_a_low_ball(rigs):
    """In the linear image the table around the foot of a ball 3 cm above it is darker than
    without the ball; far from it, unchanged."""
    rig = rigs[(640, 480)]
    renderer = scene.Renderer(rig, background_subpixels=1)
    renderer.lighting = dataclasses.replace(renderer.lighting, flicker=0.0)
    centre = np.array([[-0.6, 0.2, scene.RADIUS + 0.03]])
    material = scene.ball_material('white')
    k = 1
    plain = renderer.render_linear(k, 0.0)
    with_ball = renderer.render_linear(k, 0.0, balls=[(centre, material)])
    cam = rig.cameras[k]
    near = cam.project(np.array([[-0.6, 0.2 + 0.03, 0.0], [-0.6 - 0.03, 0.2, 0.0]]))
    u_far, v_far = np.round(cam.project(np.array([[0.6, -0.4, 0.0]]))[0]).astype(int)
    for u, v in np.round(near).astype(int):
        assert with_ball[v, u].sum() < 0.9 * plain[v, u].sum()
    assert np.array_equal(with_ball[v_far, u_far], plain[v_far, u_far])


def test_sensor_response_colours_and_vignetting(rigs):
    """Without noise and JPEG a flat grey gives the response curve's level (gamma 2.2 with a
    soft shoulder) at the centre, less toward the corners; an orange patch through the RGGB
    mosaic and the demosaicing comes out orange (red > green > blue)."""
    cam = rigs[(640, 480)].cameras[0]
    sensor = scene.Sensor(noise=False, jpeg_quality=None)
    rng = np.random.default_rng(0)
    linear = np.full((cam.height, cam.width, 3), 0.3, np.float32)
    out = sensor.capture(linear, cam, rng)
    cy, cx = int(cam.K[1, 2]), int(cam.K[0, 2])
    expected = sensor.response(0.3 * sensor.exposure_scale)
    assert np.abs(out[cy - 2:cy + 3, cx - 2:cx + 3].astype(float) - expected).max() <= 1.0
    assert expected == pytest.approx(255.0 * (0.3 * sensor.exposure_scale) ** (1 / 2.2),
                                     abs=0.5)
    assert out[2, 2].mean() < out[cy, cx].mean() - 10
    assert sensor.response(2.0) < 255.0 and sensor.response(1.0) > sensor.response(0.9)
    linear[:] = scene.BALL_ALBEDO['orange']
    b, g, r = sensor.capture(linear, cam, rng)[cy, cx].astype(int)
    assert r > g + 40 and g > b + 40


def test_scene_is_deterministic_and_stamps_exposure_mid_times():
    rig = synth.demo_rig()
    one = Rig([rig.cameras[1]], rig.fps)
    f = scene.simulate(scene.serve(8.0, 40.0, 10.0), 0.0, 0.5)
    renderer = scene.Renderer(one, background_subpixels=1)
    runs = []
    for _ in range(2):
        frames, truth = scene.render_scene(one, [f], 'orange', t_begin=0.28, t_end=0.31,
                                           renderer=renderer, seed=3)
        runs.append(list(frames))
    assert [t for t, _, _ in runs[0]] == pytest.approx(0.28 + np.arange(5) / rig.fps)
    assert all(np.array_equal(a[2], b[2]) for a, b in zip(*runs, strict=True))
    assert np.allclose(truth[0]['state'], f.state(truth[0]['t']))
    frames, _ = scene.render_scene(one, [f], 'orange', t_begin=0.28, t_end=0.31,
                                   renderer=renderer, seed=4)
    assert not np.array_equal(next(frames)[2], runs[0][0][2])
