"""tt-perceive judged on side-light scenes from a second independent renderer.

The scenes come from ``bench/side_light_scene.py``, a ray-cast renderer written apart from
``tt_perception.synth`` and ``src/tt_perception/test/independent_scene.py`` (its own cameras
and rig file as well): a green table, a light-grey floor, a key light from the side with cast
shadows, a net with a mesh that hides the ball in part, a 1280 x 1024 and an 800 x 600 camera
with different lenses at 100 fps, a linear response; three served balls per scene (flat,
topspin, backspin with sidespin) with its own drag, Magnus and bounce. Cases (the renderer's
``CASES``):

- ``base``: white ball, plain walls, no blur, noise or JPEG;
- ``all``: + striped walls and people, motion blur (7 sub-exposures over 3 ms), noise
  (sigma 3 grey levels), JPEG q50;
- ``darkfloor``: ``base`` on a dark floor (albedo 0.12 instead of 0.62);
- ``all_orange_dark``: ``all`` with an orange ball on the dark floor;
- ``rolling``: ``base`` with a 5 ms top-to-bottom rolling shutter (the middle row at the
  frame's time), told to tt-perceive as each camera's ``readout_time`` in a copy of the
  renderer's rig (``rig_readout.yaml``), as a user gives a camera's; perceived once more
  with the renderer's rig as it is (no readout told), reported as ``without_readout_time``.

The renderer's self-check (:func:`side_light_scene.check`) runs first; the bench stops if it
fails. Each case is rendered once into ``bench/results/side_light_scene/CASE`` (about 380 MB
for the five; the root .gitignore keeps it out of git) and re-rendered only when
the case's options or the renderer's source change. ``tt-perceive`` runs on it as its own
process, with ``--colour`` the ball's colour, ``--exposure`` the case's exposure (at least
0.1 ms), as docs/perception.md tells a user to set them, the other options at their
defaults (the states as the live node publishes them; each camera's blur estimated from the
ball's outline fits, reported as ``estimated_image_blur_px``); its tracks go to a temporary
folder. Each case is perceived a second time with ``--image-blur`` its cameras' own blur
(:func:`camera_blur`: 0 for these sharp cameras, 0.4 px with JPEG), a third with 0.6 px
(a Bayer camera's, perception_node's default), and a fourth without ``--exposure`` (each
camera's exposure estimated too, as tt-perceive does by default), reported as
``with_camera_blur``, ``with_image_blur_0.6`` and ``with_exposure_estimated``, not
judged. Scored against the renderer's truth (per camera 0
frame with the ball in flight):

- ``tracks``, ``tracks_per_flight`` (tracks whose median error is within 5 cm, given to the
  flight most of their states fall in) and ``false_tracks`` (the others);
- over the frames in which both cameras see the whole ball (its centre more than 8 px inside
  both images and not hidden by the net): ``coverage_pct`` (frames with a state),
  ``rms3d_mm``, ``mean_mm`` and ``rms_axis_mm`` (x, y, z), ``max3d_mm``; ``steady_rms3d_mm``
  and ``steady_mean_mm`` over the states 50 ms or more into their track and more than 80 ms
  from a bounce; the velocity error (m/s) over the states 50 ms or more into their track:
  ``vel_err_mean``, ``vel_err_p95``, ``vel_err_max`` and ``vel_err_max_nobounce`` (more than
  30 ms from a bounce); a frame with states from two tracks counts its first track's;
- ``partial``: the same over the frames in which the net hides part of the ball in a camera;
- ``flights``: coverage and 3-D RMS per flight; ``missing_frames``: the frames counted in
  ``coverage_pct`` without a state.

Targets (``TARGETS``) for ``base``, ``all``, ``darkfloor`` and ``all_orange_dark``: one track
per flight, no false track, coverage >= 95 %, 3-D RMS <= 2.0 mm. ``passed``: every judged
case within all four. ``rolling`` is reported, not judged: its second flight is launched in
view, and the renderer draws the ball at its launch point in the rows exposed before the
launch (a ball that was not there), which puts that track's first states 5-15 mm off
whatever the readout told.
"""

import csv
import hashlib
import json
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import yaml

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import side_light_scene as scene  # noqa: E402

CASES = ('base', 'all', 'darkfloor', 'all_orange_dark', 'rolling')
JUDGED = ('base', 'all', 'darkfloor', 'all_orange_dark')
TARGETS = {'tracks_per_flight': 1, 'false_tracks': 0, 'coverage_pct_min': 95.0,
           'rms3d_mm_max': 2.0}
SCENES = HERE / 'results' / 'side_light_scene'
VERSION = 1
"""Bumped when the cached scene's layout changes (the renderer's source is hashed too)."""
MARGIN_PX = 8
FALSE_TRACK_M = 0.05
SETTLE_S = 0.05
STEADY_FROM_BOUNCE_S = 0.08
VELOCITY_FROM_BOUNCE_S = 0.03


JPEG_BLUR_PX = 0.4
"""``image_blur`` of a camera whose only blur is its JPEG after a linear response, px
(docs/perception.md: about 0.4 for JPEG q30; this renderer's q50 blurs no more)."""


def case_options(name):
    return dict(scene.BASE, **scene.CASES[name])


def camera_blur(opts):
    """The blur of a case's cameras as tt-perceive's ``--image-blur`` takes it, px: the
    renderer's cameras have no lens blur and no mosaic (its supersampling is the pixel's own
    area, which the outline fit models), so 0, or JPEG_BLUR_PX with JPEG; the motion blur is
    ``--exposure``'s."""
    return JPEG_BLUR_PX if opts['jpeg'] else 0.0


def make_scene(name, folder=SCENES):
    """``folder/name``, rendered unless a render of the same request is there; returns
    (its path, render seconds or None when cached)."""
    folder.mkdir(parents=True, exist_ok=True)     # in the root .gitignore: never committed
    request = {'version': VERSION, 'case': name, 'opts': case_options(name),
               'renderer_sha256': hashlib.sha256(
                   pathlib.Path(scene.__file__).read_bytes()).hexdigest()}
    out = folder / name
    done = out / 'scene.json'
    if done.exists() and json.loads(done.read_text()).get('request') == request:
        return out, None
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    scene.render_case(name, str(folder))
    render_s = time.perf_counter() - start
    done.write_text(json.dumps({'request': request, 'render_s': round(render_s, 1)},
                               indent=1))
    return out, render_s


def perceive_command():
    exe = shutil.which('tt-perceive')
    if exe:
        return [exe]
    return [sys.executable, '-c',
            'import sys; from tt_perception.entry import tt_perceive; sys.exit(tt_perceive())']


def told_rig(case_dir, opts):
    """The case's rig as a user gives it to tt-perceive: the renderer's, with each camera's
    rolling-shutter readout (``readout_time``, s) where the case has one."""
    rig = case_dir / 'rig.yaml'
    if not opts['rolling']:
        return rig
    data = yaml.safe_load(rig.read_text())
    for camera in data['cameras']:
        camera['readout_time'] = opts['rolling']
    told = case_dir / 'rig_readout.yaml'
    told.write_text(yaml.safe_dump(data, sort_keys=False))
    return told


def perceive(case_dir, tracks, opts, image_blur=None, told_exposure=True, told_readout=True):
    """tt-perceive on the case's rig, as a user runs it (``image_blur``: its
    ``--image-blur``, None for the default; ``told_exposure``: ``--exposure`` the case's,
    else the default, estimated; ``told_readout``: the rig of :func:`told_rig`, else the
    renderer's); returns (seconds, the blurs and the exposures (s) it estimated, per camera:
    empty where told)."""
    rig = told_rig(case_dir, opts) if told_readout else case_dir / 'rig.yaml'
    cmd = [*perceive_command(), '--rig', str(rig), '--out', str(tracks),
           '--colour', opts['colour']]
    if told_exposure:
        cmd += ['--exposure', repr(max(opts['exposure'], 1e-4))]
    if image_blur is not None:
        cmd += ['--image-blur', repr(image_blur)]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise RuntimeError(f'tt-perceive exit {proc.returncode}: {proc.stderr[-2000:]}')
    blurs = [float(b) for b in re.findall(r'image_blur ([0-9.]+) px estimated', proc.stderr)]
    exposures = [float(e) * 1e-3
                 for e in re.findall(r'exposure ([0-9.]+) ms estimated', proc.stderr)]
    return time.perf_counter() - start, blurs, exposures


def load_csv(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in (rows[0] if rows else [])}


def stats(mask, state, truth, bounces):
    """Coverage and errors over the truth rows in ``mask`` (see the module docstring)."""
    P = np.column_stack([truth['x'], truth['y'], truth['z']])
    V = np.column_stack([truth['vx'], truth['vy'], truth['vz']])
    rows = [i for i in np.nonzero(mask)[0] if i in state]
    res = {'frames': int(mask.sum()), 'with_state': len(rows),
           'coverage_pct': round(100.0 * len(rows) / max(int(mask.sum()), 1), 2)}
    if not rows:
        return res

    def from_bounce(i):
        return min((abs(truth['t'][i] - b) for b in bounces), default=np.inf)

    e = np.array([state[i][0] - P[i] for i in rows]) * 1e3
    res['rms3d_mm'] = round(float(np.sqrt((e ** 2).sum(1).mean())), 3)
    res['mean_mm'] = e.mean(0).round(3).tolist()
    res['rms_axis_mm'] = np.sqrt((e ** 2).mean(0)).round(3).tolist()
    res['max3d_mm'] = round(float(np.linalg.norm(e, axis=1).max()), 2)
    steady = [i for i in rows if state[i][2] >= SETTLE_S - 1e-9
              and from_bounce(i) > STEADY_FROM_BOUNCE_S]
    if steady:
        es = np.array([state[i][0] - P[i] for i in steady]) * 1e3
        res['steady_frames'] = len(steady)
        res['steady_mean_mm'] = es.mean(0).round(3).tolist()
        res['steady_rms3d_mm'] = round(float(np.sqrt((es ** 2).sum(1).mean())), 3)
    judged = [i for i in rows if state[i][2] >= SETTLE_S - 1e-9]
    if judged:
        dv = np.array([np.linalg.norm(state[i][1] - V[i]) for i in judged])
        nb = np.array([from_bounce(i) > VELOCITY_FROM_BOUNCE_S for i in judged])
        res['vel_err_mean'] = round(float(dv.mean()), 4)
        res['vel_err_p95'] = round(float(np.percentile(dv, 95)), 4)
        res['vel_err_max'] = round(float(dv.max()), 4)
        if nb.any():
            res['vel_err_mean_nobounce'] = round(float(dv[nb].mean()), 4)
            res['vel_err_max_nobounce'] = round(float(dv[nb].max()), 4)
    return res


def score(case_dir, tracks_dir):
    """The numbers of the module docstring for tt-perceive's tracks of one case."""
    meta = json.loads((case_dir / 'meta.json').read_text())
    fps = meta['opts']['fps']
    truth = load_csv(case_dir / 'truth.csv')
    inimg = np.ones(len(truth['t']), bool)
    for k, cam in enumerate(scene.make_cams(meta['opts']['camvariant'])):
        u, v = truth[f'u{k}'], truth[f'v{k}']
        inimg &= ((u > MARGIN_PX) & (u < cam.w - 1 - MARGIN_PX)
                  & (v > MARGIN_PX) & (v < cam.h - 1 - MARGIN_PX))
    full = inimg & (truth['vis0'] > 0.999) & (truth['vis1'] > 0.999)
    part = inimg & ~full & (truth['vis0'] > 0) & (truth['vis1'] > 0)
    frame_of = {int(n): i for i, n in enumerate(truth['frame'])}
    P = np.column_stack([truth['x'], truth['y'], truth['z']])
    flights = len(meta['starts'])
    per_flight = {i: [] for i in range(flights)}
    false_tracks = []
    state = {}    # truth row -> (position, velocity, time into its track, track)
    names = sorted(p.name for p in tracks_dir.glob('track_*.csv'))
    for name in names:
        d = load_csv(tracks_dir / name)
        if not d:
            continue
        idx = np.array([frame_of.get(int(k), -1) for k in np.round(d['t'] * fps).astype(int)])
        ok = idx >= 0
        if not ok.any():
            false_tracks.append({'track': name, 'states': len(idx), 'why': 'outside flights'})
            continue
        est = np.column_stack([d['x'], d['y'], d['z']])
        err = np.linalg.norm(est[ok] - P[idx[ok]], axis=1)
        if np.median(err) > FALSE_TRACK_M:
            false_tracks.append({'track': name, 'states': len(idx),
                                 'why': f'median error {np.median(err) * 1e3:.0f} mm'})
            continue
        per_flight[int(np.bincount(truth['ball'][idx[ok]].astype(int)).argmax())].append(name)
        for j in np.nonzero(ok)[0]:
            state.setdefault(idx[j], (est[j], np.array([d['vx'][j], d['vy'][j], d['vz'][j]]),
                                      d['t'][j] - d['t'][0], name))
    bounces = [b for fl in meta['bounces'] for b in fl]
    out = {'tracks': len(names), 'tracks_per_flight': [len(v) for v in per_flight.values()],
           'false_tracks': len(false_tracks), 'false_track_list': false_tracks}
    out.update(stats(full, state, truth, bounces))
    out['partial'] = stats(part, state, truth, bounces)
    out['flights'] = [{k: v for k, v in stats(full & (truth['ball'] == i), state, truth,
                                               bounces).items()
                       if k in ('frames', 'coverage_pct', 'rms3d_mm')}
                      for i in range(flights)]
    out['missing_frames'] = [int(truth['frame'][i]) for i in np.nonzero(full)[0]
                             if i not in state]
    return out


def checks(row):
    return {
        'one_track_per_flight': all(n == TARGETS['tracks_per_flight']
                                    for n in row['tracks_per_flight']),
        'no_false_track': row['false_tracks'] == TARGETS['false_tracks'],
        'coverage_ok': row['coverage_pct'] >= TARGETS['coverage_pct_min'],
        'rms_ok': row.get('rms3d_mm') is not None
        and row['rms3d_mm'] <= TARGETS['rms3d_mm_max'],
    }


def run():
    out = {'targets': TARGETS, 'judged': list(JUDGED), 'scene_folder': str(SCENES)}
    out['renderer_check'] = scene.check()
    if not out['renderer_check']['passed']:
        raise RuntimeError(f'side_light_scene.check failed: {out["renderer_check"]}')
    out['cases'] = {}
    for name in CASES:
        opts = case_options(name)
        case_dir, render_s = make_scene(name)
        with tempfile.TemporaryDirectory(prefix=f'side_light_{name}_') as tmp:
            tracks = pathlib.Path(tmp) / 'tracks'
            perceive_s, estimated, _ = perceive(case_dir, tracks, opts)
            row = score(case_dir, tracks)
            told = {}
            variants = [('with_camera_blur', camera_blur(opts), True, True),
                        ('with_image_blur_0.6', 0.6, True, True),
                        ('with_exposure_estimated', None, False, True)]
            if opts['rolling']:
                variants.append(('without_readout_time', None, True, False))
            for key, blur, told_exposure, told_readout in variants:
                _, blurs, exposures = perceive(case_dir, pathlib.Path(tmp) / key, opts, blur,
                                               told_exposure, told_readout)
                other = score(case_dir, pathlib.Path(tmp) / key)
                told[key] = {k: other.get(k) for k in (
                    'coverage_pct', 'rms3d_mm', 'mean_mm', 'max3d_mm', 'tracks_per_flight',
                    'false_tracks')}
                if told_exposure and blur is not None:
                    told[key]['image_blur_px'] = blur
                elif told_exposure:
                    told[key]['estimated_image_blur_px'] = blurs
                else:
                    told[key].update(
                        estimated_exposure_ms=[round(e * 1e3, 3) for e in exposures],
                        estimated_image_blur_px=blurs)
                if name in JUDGED:
                    told[key]['within_targets'] = all(checks(other).values())
        row['colour'] = opts['colour']
        row['exposure_s'] = max(opts['exposure'], 1e-4)
        row['estimated_image_blur_px'] = estimated
        row.update(told)
        row['render_s'] = None if render_s is None else round(render_s, 1)
        row['cached_scene'] = render_s is None
        row['perceive_s'] = round(perceive_s, 1)
        row['frames_per_camera'] = len(list((case_dir / 'cam0').glob('*.png')))
        if name in JUDGED:
            row['checks'] = checks(row)
            row['passed'] = all(row['checks'].values())
        print(name, {k: row.get(k) for k in ('coverage_pct', 'rms3d_mm', 'mean_mm',
                                             'tracks_per_flight', 'false_tracks', 'passed',
                                             'estimated_image_blur_px', 'render_s',
                                             'perceive_s')},
              {k: row[k]['rms3d_mm'] for k in told}, flush=True)
        out['cases'][name] = row
    out['passed'] = all(out['cases'][n]['passed'] for n in JUDGED)
    return out


if __name__ == '__main__':
    from run_all import bench_main
    sys.exit(bench_main(__file__, run))
