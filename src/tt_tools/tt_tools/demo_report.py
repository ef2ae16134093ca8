"""Compare what the graph published with the truth of the recording (pure, no rclpy).

For each true ball the decision time is ``DECISION_LEAD`` before its true hit: the robot acts
on the latest prediction and strike command stamped before then. Errors:

- perceived state: position RMS over the ball's BallStates, and velocity and spin at the
  decision time, against the true flight;
- prediction: bounce zone and hit point (and time) against the true ones;
- strike: the command's expected landing, and where the true ball really lands when struck
  with the commanded racket (eq. 7 and eq. 8 from the true hit state).
"""

from dataclasses import dataclass, field

import numpy as np
from tt_prediction.ball import (
    HALF_LENGTH,
    HALF_WIDTH,
    NET_HALF_WIDTH,
    NET_HEIGHT,
    ZONE_LENGTH,
    ZONE_WIDTH,
)

from .scenario import landing_after_stroke

DECISION_LEAD = 0.15
"""Time before the true hit at which the robot commits to a stroke, s."""


@dataclass
class BallResult:
    index: int
    truth: object
    states: list = field(default_factory=list)
    position_rms_mm: float = np.nan
    velocity_err: float = np.nan
    spin_true: np.ndarray = None
    spin_est: np.ndarray = None
    prediction: dict = None
    hit_err_mm: float = np.nan
    hit_time_err_ms: float = np.nan
    command: dict = None
    true_landing: np.ndarray = None
    true_landing_zone: int = 0
    return_path: np.ndarray = None


TIME_KEYS = ('t', 'hit_t', 'bounce_t')


def shift_times(outputs, base):
    """Outputs with every time (stamp, hit and bounce time) minus ``base`` s (in place)."""
    for records in outputs.values():
        for record in records:
            for key in TIME_KEYS:
                if key in record:
                    record[key] -= base
    return outputs


def _latest(records, t0, t1):
    inside = [r for r in records if t0 <= r['t'] <= t1]
    return inside[-1] if inside else None


def evaluate(truths, outputs, params):
    """One BallResult per true ball from the collected outputs (see collector.TOPICS)."""
    results = []
    for i, truth in enumerate(truths):
        t0, t_hit = truth.ball.launch_time, truth.hit_time
        decision = t_hit - DECISION_LEAD
        result = BallResult(i + 1, truth)
        states = [s for s in outputs['/ball/state'] if t0 <= s['t'] <= t_hit]
        result.states = states
        if states:
            t = np.array([s['t'] for s in states])
            true = truth.state_at(t, params)
            p = np.array([s['p'] for s in states])
            err = np.linalg.norm(p - true[:, :3], axis=1)
            result.position_rms_mm = 1e3 * float(np.sqrt(np.nanmean(err ** 2)))
            last = _latest(states, t0, decision)
            if last is not None:
                true_last = truth.state_at(last['t'], params)[0]
                result.velocity_err = float(np.linalg.norm(last['v'] - true_last[3:6]))
                result.spin_true, result.spin_est = true_last[6:9], last['w']
        result.prediction = _latest(outputs['/ball/prediction'], t0, decision)
        pred = result.prediction
        if pred is not None and pred['hit_valid']:
            result.hit_err_mm = 1e3 * float(np.linalg.norm(pred['hit_p'] - truth.hit_state[:3]))
            result.hit_time_err_ms = 1e3 * (pred['hit_t'] - t_hit)
        result.command = _latest(outputs['/strike/command'], t0, decision)
        cmd = result.command
        if cmd is not None and cmd['feasible']:
            point, zone, half, path = landing_after_stroke(
                truth.hit_state, t_hit, cmd['normal'], cmd['racket_v'], params, path_points=60)
            result.true_landing, result.return_path = point, path
            result.true_landing_zone = zone if half == 1 else 0
        results.append(result)
    return results


def balls_missed(results):
    """What each ball lacked of a perceived state, a prediction and a strike command, as
    short phrases (``'ball 3: no prediction'``); empty when every ball got all three."""
    missed = []
    for r in results:
        lacks = [what for what, got in (('state', bool(r.states)),
                                        ('prediction', r.prediction is not None),
                                        ('strike command', r.command is not None)) if not got]
        if lacks:
            missed.append(f'ball {r.index}: no {", no ".join(lacks)}')
    return missed


def _fmt(value, spec):
    return '-' if value is None or not np.isfinite(value) else format(value, spec)


def format_table(results, target_zone):
    """A text table, one row per ball."""
    head = ('ball', 'states', 'pos rms mm', 'vel err m/s', '|w| true/est rad/s',
            'bounce zone true/pred', 'hit err mm', 'hit dt ms', 'strike',
            'racket v m/s', f'lands (target {target_zone}) expected/true')
    rows = []
    for r in results:
        pred, cmd = r.prediction, r.command
        spin = '-'
        if r.spin_true is not None:
            spin = f'{np.linalg.norm(r.spin_true):.0f}/{np.linalg.norm(r.spin_est):.0f}'
        zone_pred = f'{pred["bounce_zone"]}' if pred and pred['bounce_valid'] else '-'
        strike = cmd['status'] if cmd else 'none'
        racket = _fmt(np.linalg.norm(cmd['racket_v']) if cmd and cmd['feasible'] else None,
                      '.2f')
        lands = '-'
        if cmd and cmd['feasible']:
            lands = f'{cmd["landing_zone"]}/{r.true_landing_zone or "off"}'
        rows.append((str(r.index), str(len(r.states)), _fmt(r.position_rms_mm, '.1f'),
                     _fmt(r.velocity_err, '.3f'), spin,
                     f'{r.truth.bounce_zone}/{zone_pred}', _fmt(r.hit_err_mm, '.1f'),
                     _fmt(r.hit_time_err_ms, '.1f'), strike, racket, lands))
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(head)]
    lines = ['  '.join(h.rjust(w) for h, w in zip(head, widths, strict=True))]
    lines.append('  '.join('-' * w for w in widths))
    lines += ['  '.join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in rows]
    lines.append(f'(decision time: {DECISION_LEAD * 1e3:.0f} ms before the true hit; '
                 'robot half: bounce zones on x < 0; landing zones on the opponent half)')
    return '\n'.join(lines)


def _draw_table(ax_top, ax_side):
    from matplotlib.patches import Rectangle

    hl, hw = HALF_LENGTH, HALF_WIDTH
    ax_top.add_patch(Rectangle((-hl, -hw), 2 * hl, 2 * hw, fill=False, color='0.3'))
    for k in range(1, 3):
        for sign in (-1, 1):
            ax_top.plot([sign * k * ZONE_LENGTH] * 2, [-hw, hw], color='0.8', lw=0.8)
        ax_top.plot([-hl, hl], [hw - k * ZONE_WIDTH] * 2, color='0.8', lw=0.8)
    ax_top.plot([0, 0], [-NET_HALF_WIDTH, NET_HALF_WIDTH], color='k', lw=2)
    ax_side.plot([-hl, hl], [0, 0], color='0.3', lw=2)
    ax_side.plot([0, 0], [0, NET_HEIGHT], color='k', lw=2)


def plot(results, params, path):
    """Top (x-y) and side (x-z) views: true and measured tracks, predicted bounce and hit,
    racket normals and expected landings. Returns the path written."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, (ax_top, ax_side) = plt.subplots(2, 1, figsize=(11, 9))
    _draw_table(ax_top, ax_side)
    colours = plt.rcParams['axes.prop_cycle'].by_key()['color']
    for r in results:
        c = colours[(r.index - 1) % len(colours)]
        t = np.linspace(r.truth.ball.launch_time, r.truth.hit_time, 200)
        true = r.truth.state_at(t, params)
        ax_top.plot(true[:, 0], true[:, 1], color=c, lw=1, label=f'ball {r.index} truth')
        ax_side.plot(true[:, 0], true[:, 2], color=c, lw=1)
        if r.states:
            p = np.array([s['p'] for s in r.states])
            ax_top.plot(p[:, 0], p[:, 1], '.', color=c, ms=3)
            ax_side.plot(p[:, 0], p[:, 2], '.', color=c, ms=3)
        pred = r.prediction
        if pred and pred['bounce_valid']:
            ax_top.plot(*pred['bounce_p'][:2], 'x', color=c, ms=9)
        if pred and pred['hit_valid']:
            ax_top.plot(*pred['hit_p'][:2], 'o', mfc='none', color=c, ms=9)
            ax_side.plot(pred['hit_p'][0], pred['hit_p'][2], 'o', mfc='none', color=c, ms=9)
        cmd = r.command
        if cmd and cmd['feasible']:
            hp, n = cmd['hit_p'], 0.15 * cmd['normal']
            ax_top.annotate('', hp[:2] + n[:2], hp[:2], arrowprops={'color': c, 'width': 1.5})
            ax_side.annotate('', (hp[0] + n[0], hp[2] + n[2]), (hp[0], hp[2]),
                             arrowprops={'color': c, 'width': 1.5})
            ax_top.plot(*cmd['landing_p'][:2], '*', color=c, ms=12)
            if r.true_landing is not None:
                ax_top.plot(*r.true_landing[:2], '+', color=c, ms=12)
            if r.return_path is not None and len(r.return_path):
                ax_top.plot(r.return_path[:, 0], r.return_path[:, 1], '--', color=c, lw=1)
                ax_side.plot(r.return_path[:, 0], r.return_path[:, 2], '--', color=c, lw=1)
    ax_top.set(xlabel='x (m)', ylabel='y (m)', aspect='equal',
               title='top view: line truth, dots perceived, x predicted bounce, o predicted hit,\n'
                     'arrow racket normal, dashed true return, * expected / + true landing')
    ax_side.set(xlabel='x (m)', ylabel='z (m)', title='side view', ylim=(-0.05, 0.75))
    ax_top.legend(loc='upper right', fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
