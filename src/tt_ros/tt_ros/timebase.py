"""Whether a message's stamp and the node clock are on one time base (pure: no rclpy).

Live stamps and the wall clock agree; a recording replayed with its clock (``ros2 bag play
--clock``, perception_node ``publish_clock``) and ``use_sim_time`` agree too. A stamp more
than :data:`TIME_BASE_MISMATCH_S` from the node clock comes from another time base (video
time from 0 against the wall clock, a synthetic recording stamped in 2023 replayed today):
checks of age or lead time against the clock mean nothing for it.
"""

TIME_BASE_MISMATCH_S = 3600.0
"""A stamp this far from the node clock, either way, is on another time base, s."""
MAX_TIME_BASES = 4
"""Other time bases a :class:`TimeBaseCheck` warns of, one warning each."""


def same_time_base(stamp_s, now_s):
    """Whether ``stamp_s`` and the node clock's ``now_s`` (s, 0: no /clock yet under
    use_sim_time) can be compared."""
    return now_s != 0 and abs(now_s - stamp_s) <= TIME_BASE_MISMATCH_S


def mismatch_warning(offset_s):
    """The one-line warning for stamps ``offset_s`` s from the node clock."""
    return (f'stamps are {offset_s:.0f} s from the node clock: another time base (a recording '
            'without /clock?), so time checks against the clock are off for them; run with '
            'use_sim_time:=true and a /clock source (ros2 bag play --clock, perception_node '
            'publish_clock:=true)')


class TimeBaseCheck:
    """:func:`same_time_base` for a node's stamps, warning once per time base: the first
    stamp on another time base than a running clock is reported through ``warn`` (a
    logger's warning) with :func:`mismatch_warning`, and so is the first on each other time
    base after it (an offset from the node clock more than TIME_BASE_MISMATCH_S from every
    one warned of: stamps 2 h ahead after stamps 2 h behind were not reported), up to
    :data:`MAX_TIME_BASES`; then one last warning says that no more are told (stamps
    scattered over hours, a clock sending garbage, would otherwise warn on every message)."""

    def __init__(self, warn):
        self._warn = warn
        self.warned = []            # the offsets warned of, s (at most MAX_TIME_BASES)
        self.silent = False         # more time bases than those: no more warnings

    def __call__(self, stamp_s, now_s):
        """Whether ``stamp_s`` can be compared with the node clock's ``now_s`` (s, 0: no
        /clock yet under use_sim_time, which is not warned about)."""
        if same_time_base(stamp_s, now_s):
            return True
        offset = stamp_s - now_s
        if (now_s and not self.silent
                and all(abs(offset - w) > TIME_BASE_MISMATCH_S for w in self.warned)):
            if len(self.warned) < MAX_TIME_BASES:
                self.warned.append(offset)
                self._warn(mismatch_warning(offset))
            else:
                self.silent = True
                self._warn(f'stamps on more than {MAX_TIME_BASES} other time bases (now '
                           f'{offset:.0f} s from the node clock): a clock sending garbage? '
                           'No more warnings of time bases')
        return False
