"""bench_independent's balls and distractor seen by rigs other than the demo rig.

Every scene of bench_independent and synth's hall is seen by one rig, ``synth.demo_rig``
(a camera 1.45 m high behind the robot's end, one 1.1 m high to the side of its half: lines
of sight 13-35 degrees below the horizontal while the ball is over the table). A user's rig
is not that one. Here the same independent renderer
(``src/tt_perception/test/independent_scene.py``, its lamps, ball, sensor, JPEG) renders
bench_independent's three balls (:data:`bench_independent.BALLS`) and its distractor scene,
white and orange at 640 x 480, through two other rigs:

- ``ceiling``: two cameras 2.6 m above the floor over the robot's end, 1.3 m to either
  side, looking down at the table's middle (lines of sight 34-65 degrees below the
  horizontal), 70 degree lenses, 150 fps;
- ``wide_side``: a camera 0.9 m high 2.2 m to the side of the table's middle and one 1.2 m
  high behind the robot's end and to the other side, 80 degree lenses with stronger barrel
  distortion, 120 fps.

Each is scored as bench_independent scores its rows (:func:`bench_independent.ball_scene`,
the pipeline at its defaults, told the renderer's gamma): position RMS, mean error per
axis, coverage, tracks, velocity and spin (reported), and the distractor scene's states.
``passed`` per rig: every ball within issue 15's limits on position RMS, mean error per
axis, coverage and one track, and no state from the distractor, as bench_independent's
``passed``. docs/perception_measured.md, "Other rigs", says what they show.
"""

import sys
import time

import bench_independent as bi
import cv2
import numpy as np

from tt_perception import synth

RIGS = {
    'ceiling': {'poses': (((-1.6, -1.3, 2.6), (-0.3, 0.0, 0.1)),
                          ((-1.6, 1.3, 2.6), (-0.3, 0.0, 0.1))),
                'fov_deg': 70.0, 'dist': (-0.11, 0.04, 0.0, 0.0, 0.0), 'fps': 150.0},
    'wide_side': {'poses': (((-0.8, -2.2, 0.9), (0.0, 0.0, 0.15)),
                            ((-2.8, 1.0, 1.2), (0.0, 0.0, 0.1))),
                  'fov_deg': 80.0, 'dist': (-0.25, 0.08, 0.0008, -0.0005, 0.0), 'fps': 120.0},
}
"""Camera poses (eye, target; table frame, m), horizontal field of view, plumb-bob
distortion and frame rate of each rig."""
SIZE = (640, 480)
COLOURS = ('white', 'orange')


def make_rig(poses, fov_deg, dist, fps):
    """A rig of :data:`RIGS` at :data:`SIZE` (its principal point 4 px left of and 3 px
    below the image's centre)."""
    return synth.look_at_rig(poses, fov_deg, dist, fps, *SIZE, principal_offset=(-4.0, 3.0))


def sight_elevations_deg(rig, flight):
    """Range over the flight of each camera's line of sight's angle below the horizontal."""
    t = np.linspace(flight.t0, flight.t_end, 50)
    positions = flight.state(t)[:, :3]
    out = []
    for cam in rig.cameras:
        sight = cam.centre[None] - positions
        angle = np.degrees(np.arcsin(sight[:, 2] / np.linalg.norm(sight, axis=1)))
        out.append([round(float(angle.min()), 1), round(float(angle.max()), 1)])
    return out


def run():
    cv2.setNumThreads(1)
    flights = {name: bi.scene.simulate(bi.scene.serve(**kw), 0.0, bi.T_END)
               for name, kw in bi.BALLS.items()}
    out = {'limits': bi.LIMITS, 'rigs': {}}
    for rig_name, spec in RIGS.items():
        rig = make_rig(**spec)
        renderer = bi.scene.Renderer(rig, seed=0)
        start = time.perf_counter()
        entry = {'rig': dict(spec), 'combinations': {},
                 'sight_below_horizontal_deg': {
                     name: sight_elevations_deg(rig, f) for name, f in flights.items()}}
        for colour in COLOURS:
            rows = {name: bi.ball_scene(rig, renderer, colour, f)
                    for name, f in flights.items()}
            distractor = bi.distractor_scene(rig, renderer, colour)
            entry['combinations'][colour] = {
                'passed': all(r['passed'] for r in rows.values()) and distractor['passed'],
                'balls': rows, 'distractor': distractor}
            print(rig_name, colour, {n: (r.get('position_rms_mm'), r.get('mean_error_mm'),
                                         r['coverage'], r['tracks'])
                                     for n, r in rows.items()},
                  'distractor states', distractor['states'], flush=True)
        entry['passed'] = all(c['passed'] for c in entry['combinations'].values())
        entry['wall_s'] = round(time.perf_counter() - start, 1)
        out['rigs'][rig_name] = entry
    out['passed'] = all(r['passed'] for r in out['rigs'].values())
    return out


if __name__ == '__main__':
    from run_all import bench_main
    sys.exit(bench_main(__file__, run))
