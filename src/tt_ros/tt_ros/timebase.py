"""Whether a message's stamp and the node clock are on one time base (pure: no rclpy).

Live stamps and the wall clock agree; a recording replayed with its clock (``ros2 bag play
--clock``, perception_node ``publish_clock``) and ``use_sim_time`` agree too. A stamp more
than :data:`TIME_BASE_MISMATCH_S` from the node clock comes from another time base (video
time from 0 against the wall clock, a synthetic recording stamped in 2023 replayed today):
checks of age or lead time against the clock mean nothing for it.
"""

import time

TIME_BASE_MISMATCH_S = 3600.0
"""A stamp this far from the node clock, either way, is on another time base, s."""
MAX_TIME_BASES = 4
"""Other time bases a :class:`TimeBaseCheck` warns of, one warning each."""
NO_CLOCK_S = 2.0
"""Messages coming this long (wall time) under use_sim_time with no /clock are warned of, s."""
NO_CLOCK_WARNING = ('use_sim_time is true but no /clock has come: the time checks against the '
                    'clock are off until one does (ros2 bag play --clock, perception_node '
                    'publish_clock:=true), or run without use_sim_time')


def same_time_base(stamp_s, now_s):
    """Whether ``stamp_s`` and the node clock's ``now_s`` (s, 0: no /clock yet under
    use_sim_time) can be compared."""
    return now_s != 0 and abs(now_s - stamp_s) <= TIME_BASE_MISMATCH_S


def mismatch_warning(offset_s):
    """The one-line warning for stamps ``offset_s`` s from the node clock."""
    return (f'stamps are {offset_s:.0f} s from the node clock: another time base (a recording '
            'without /clock, or a live publisher stamping with its own clock?), so time checks '
            "against the clock are off for them; live, stamp in ROS time (a camera's "
            'exposure mapped onto the node clock); replayed, run with use_sim_time:=true and a '
            "/clock on the stamps' time base (ros2 bag play --clock publishes the bag's record "
            'times: for stamps in video time play the /clock the bag recorded, as a topic, '
            'without --clock; perception_node publish_clock:=true)')


class TimeBaseCheck:
    """:func:`same_time_base` for a node's stamps, warning once per time base: the first
    stamp on another time base than a running clock is reported through ``warn`` (a
    logger's warning) with :func:`mismatch_warning`, and so is the first on each other time
    base after it (an offset from the node clock more than TIME_BASE_MISMATCH_S from every
    one warned of: stamps 2 h ahead after stamps 2 h behind were not reported), up to
    :data:`MAX_TIME_BASES`; then one last warning says that no more are told (stamps
    scattered over hours, a clock sending garbage, would otherwise warn on every message).
    Messages that keep coming under use_sim_time with no /clock are warned of once: a user
    who set use_sim_time on a live graph had every time check off without a word.
    ``monotonic``: the wall clock (s) that times that."""

    def __init__(self, warn, monotonic=time.monotonic):
        self._warn = warn
        self._monotonic = monotonic
        self.warned = []            # the offsets warned of, s (at most MAX_TIME_BASES)
        self.silent = False         # more time bases than those: no more warnings
        self._no_clock_since = None     # wall time of the first message without a clock
        self.no_clock_warned = False

    def __call__(self, stamp_s, now_s):
        """Whether ``stamp_s`` can be compared with the node clock's ``now_s`` (s, 0: no
        /clock yet under use_sim_time: warned of once, with NO_CLOCK_WARNING, when messages
        have come for NO_CLOCK_S without one)."""
        if not now_s:
            wall = self._monotonic()
            if self._no_clock_since is None:
                self._no_clock_since = wall
            elif not self.no_clock_warned and wall - self._no_clock_since >= NO_CLOCK_S:
                self.no_clock_warned = True
                self._warn(NO_CLOCK_WARNING)
            return False
        if same_time_base(stamp_s, now_s):
            return True
        offset = stamp_s - now_s
        if (not self.silent
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
