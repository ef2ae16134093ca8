"""How late this machine wakes a thread that asks to run every millisecond (a canary).

``python bench/machine_stalls.py SECONDS`` wakes every 1 ms for SECONDS under SCHED_FIFO
(priority 50; the normal policy where that is not permitted), and prints JSON: the policy,
the lateness of the wake-ups (ms; p50, p99, p999, max), how many came more than 2, 5 and 8 ms
late, and each wake-up more than 2 ms late as [wall-clock time it was due, s; lateness, ms].
Under SCHED_FIFO no process of this machine's users comes before the canary, so what delays
it is the kernel or the hypervisor (which runs the virtual CPUs as it pleases: steal); it
costs about 2 % of one core. bench_camrate runs it beside perception_node, the way cyclictest
(rt-tests) measures a real-time machine, to tell the machine's stalls from the node's.
"""

import json
import os
import sys
import time

import numpy as np

PERIOD_NS = 1_000_000
STALL_MS = 2.0
"""A wake-up later than this is listed, with its time."""


def measure(seconds):
    policy = 'fifo'
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
    except (PermissionError, OSError, AttributeError):
        policy = 'normal'
    start = time.monotonic_ns()
    wall_offset = time.time() - start / 1e9
    end = start + int(seconds * 1e9)
    due, late, stalls = start + PERIOD_NS, [], []
    while due < end:
        now = time.monotonic_ns()
        if due > now:
            time.sleep((due - now) / 1e9)
            now = time.monotonic_ns()
        lateness_ms = (now - due) / 1e6
        late.append(lateness_ms)
        if lateness_ms > STALL_MS:
            stalls.append([round(due / 1e9 + wall_offset, 6), round(lateness_ms, 3)])
        due = max(due + PERIOD_NS, now + PERIOD_NS // 2)     # no burst to catch up
    late = np.asarray(late)
    return {
        'policy': policy, 'wakeups': len(late),
        'late_ms': {q: round(float(np.percentile(late, p)), 3)
                    for q, p in (('p50', 50), ('p99', 99), ('p999', 99.9))} |
        {'max': round(float(late.max()), 3)},
        'over_2_ms': int((late > 2).sum()), 'over_5_ms': int((late > 5).sum()),
        'over_8_ms': int((late > 8).sum()),
        'stalls': stalls,
    }


if __name__ == '__main__':
    print(json.dumps(measure(float(sys.argv[1]))))
