"""The table as a solid body (MODEL.md, "Frames and the table") in tt's one flight kernel.

Expected outcomes worked out by hand: without air (c_d = c_m = 0) the flight is the parabola
p(t) = p0 + v0 t - (0, 0, g t^2 / 2), g = 9.8 m/s^2, which RK4 integrates exactly, so the
contacts follow from the geometry: the top is a slab z in [-0.03, 0] over |x| <= 1.37,
|y| <= 0.7625; the net the plane x = 0, |y| <= 0.915, z in [-0.03, 0.1525]; r = 0.02 m.
With air, tt's kernel is compared with the independent scipy reference (body_reference.py).
"""

import math

from body_reference import first_contact
import numpy as np
import pytest
from tt_prediction.ball import ModelParams, solid_gap
from tt_prediction.predict import predict, predict_landing

NO_AIR = ModelParams(c_d=0.0, c_m=0.0)
R = 0.02
G = 9.8


def test_solid_gap_by_geometry():
    # Over the top: the gap is the height of the ball's underside.
    assert solid_gap(0.5, 0.2, 0.05, R) == pytest.approx((0.03, 1))
    # 1 cm beyond the end line at mid-depth of the face: 1 cm - r, the table's edge kind.
    assert solid_gap(-1.38, 0.0, -0.015, R) == pytest.approx((-0.01, 2))
    # Level with the corner edge (x = -1.37, z = 0) at 3 cm and 4 cm: a 5 cm distance.
    assert solid_gap(-1.40, 0.0, 0.04, R) == pytest.approx((0.05 - R, 2))
    # Beside the net's top edge over the table (1 cm and 7.5 mm from it: 12.5 mm), and
    # beside a post (y = 0.915 + 0.01).
    assert solid_gap(0.01, 0.3, 0.16, R) == pytest.approx((0.0125 - R, 3))
    assert solid_gap(0.0, 0.925, 0.05, R) == pytest.approx((0.01 - R, 4))
    # The net's part beyond the side line (|y| in (0.7625, 0.915]) is the post's kind.
    assert solid_gap(0.015, -0.85, 0.0, R)[1] == 4


def test_struck_below_the_surface_into_the_end_face_is_a_table_edge():
    # z stays in the face's band: at x = -1.39 (t = 0.11 / 5 = 0.022 s) z = -0.0124.
    pred = predict_landing([-1.5, 0.0, -0.01, 5.0, 0.0, 0.0, 0, 0, 0], NO_AIR)
    assert pred.status == 'table_edge', pred.reason
    assert 'face' in pred.reason


def test_struck_well_below_passes_under_the_top_to_the_floor():
    # Centre below -0.03 - r all the way: floor at z = -0.74 after sqrt(2 0.64 / g) s.
    pred = predict_landing([-1.5, 0.0, -0.10, 5.0, 0.0, 0.0, 0, 0, 0], NO_AIR)
    assert pred.status == 'miss', pred.reason
    t = math.sqrt(2 * 0.64 / G)
    assert f'({-1.5 + 5 * t:.3f}, 0.000, -0.740)' in pred.reason


def test_rising_under_the_top_meets_its_underside():
    # z(t) = -0.10 + t - 4.9 t^2 reaches -0.03 - r = -0.05 at t = (1 - sqrt(0.02)) / 9.8,
    # x = -1.5 + 2.5 t = -1.281: under the footprint.
    pred = predict_landing([-1.5, 0.0, -0.10, 2.5, 0.0, 1.0, 0, 0, 0], NO_AIR)
    assert pred.status == 'table_edge', pred.reason
    t = (1 - math.sqrt(0.02)) / 9.8
    assert f'({-1.5 + 2.5 * t:.3f}, 0.000, -0.050)' in pred.reason


def test_struck_below_the_surface_steeply_clears_the_edge_and_lands():
    # Over z = 0 at x = -1.44, far from the corner; over the net at z = 0.536; lands where
    # -0.10 + 4 t - 4.9 t^2 = r: t = (4 + sqrt(16 - 19.6 * 0.12)) / 9.8, x = 0.4628: zone 5.
    pred = predict_landing([-1.5, 0.0, -0.10, 2.5, 0.0, 4.0, 0, 0, 0], NO_AIR)
    assert pred.status == 'ok', pred.reason
    t = (4 + math.sqrt(16 - 19.6 * 0.12)) / 9.8
    assert pred.landing.t == pytest.approx(t, abs=1e-9)
    assert pred.landing.p[0] == pytest.approx(-1.5 + 2.5 * t, abs=1e-8)
    assert pred.landing.zone == 5


@pytest.mark.parametrize('apex_gap, status', [(-0.001, 'table_edge'), (0.001, 'wrong_half')])
def test_grazing_the_end_edge(apex_gap, status):
    # From x = -1.67 at 6 m/s with v_z = 0.49 m/s the apex is at x = -1.37 (t = 0.05 s),
    # 0.01225 m above the start: the centre passes the corner edge (x = -1.37, z = 0) at
    # r + apex_gap. 1 mm short of r it meets the edge where (x + 1.37)^2 + z^2 = r^2,
    # x = -1.37 - sqrt(r^2 - 0.019^2) = -1.3762; 1 mm over, it clears and comes down on the
    # top where 0.021 - 4.9 tau^2 = r: x = -1.37 + 6 sqrt(0.001 / 4.9) = -1.2843.
    z0 = R + apex_gap - 0.01225
    pred = predict_landing([-1.67, 0.0, z0, 6.0, 0.0, 0.49, 0, 0, 0], NO_AIR)
    assert pred.status == status, pred.reason
    if status == 'table_edge':
        x = float(pred.reason.rsplit('(', 1)[1].split(',')[0])
        assert x == pytest.approx(-1.37 - math.sqrt(R ** 2 - 0.019 ** 2), abs=1e-3)
    else:
        assert pred.landing.p[0] == pytest.approx(-1.37 + 6 * math.sqrt(0.001 / 4.9),
                                                  abs=1e-6)


@pytest.mark.parametrize('y, status', [(0.93, 'net_post'), (0.85, 'net_post'),
                                       (0.94, 'miss'), (-0.93, 'net_post')])
def test_beside_the_table_the_net_post_or_past_it(y, status):
    # At x = 0 (t = 0.1 s) z = 0.08 - 0.049 = 0.031: level with the post. The post edge is at
    # |y| = 0.915: 1.5 cm from it (< r) meets it, 2.5 cm passes; |y| = 0.85 meets the net's
    # part beyond the side line.
    pred = predict_landing([-0.5, y, 0.08, 5.0, 0.0, 0.0, 0, 0, 0], NO_AIR)
    assert pred.status == status, pred.reason


def test_incoming_ball_low_into_the_opponents_end_face():
    # x = +1.39 at t = 0.042 s, z = -0.01 - 4.9 0.042^2 = -0.0186: in the face's band.
    pred = predict([1.6, 0.0, -0.01, -5.0, 0.0, 0.0, 0, 0, 0], NO_AIR)
    assert pred.status == 'table_edge', pred.reason
    assert pred.bounce is None and pred.hit is None


STROKES = [      # balls leaving the racket (nominal air): below, level with and over the top
    [-1.5, 0.0, -0.10, 2.5, 0.0, 4.0, 0.0, 100.0, 0.0],
    [-1.5, 0.0, -0.10, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [-1.5, 0.1, -0.01, 5.0, 0.0, 0.3, 0.0, 0.0, 0.0],
    [-1.45, 0.0, -0.12, 4.0, 0.0, 2.0, 0.0, 0.0, 0.0],
    [-1.45, 0.0, -0.12, 4.0, 0.0, 2.6, 0.0, -150.0, 0.0],
    [-1.5, 0.2, 0.2, 6.0, 0.3, 1.5, 0.0, 0.0, 0.0],
    [-0.5, 0.93, 0.08, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [-1.5, 0.7, 0.25, 5.0, 1.2, 1.0, 0.0, 0.0, 80.0],
]


@pytest.mark.parametrize('stroke', STROKES)
def test_agrees_with_the_independent_reference(stroke):
    pred = predict_landing(stroke, ModelParams())
    ref = first_contact(stroke)
    kind = {'top': 'ok' if ref['kind'] == 'top' and ref['p'][0] > 0 else 'wrong_half',
            'floor': 'miss'}.get(ref['kind'], ref['kind'])
    assert pred.status == kind, (pred.reason, ref)
    if ref['kind'] == 'top':
        np.testing.assert_allclose(pred.landing.p, ref['p'], atol=1e-6)
        assert pred.landing.t == pytest.approx(ref['t'], abs=1e-7)
