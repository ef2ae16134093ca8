"""tt_ros.timebase: which stamps can be checked against the node clock, and the warnings."""

from tt_ros.timebase import TIME_BASE_MISMATCH_S, TimeBaseCheck, same_time_base

NOW = 1_790_000_000.0           # a wall clock in 2026, s


def test_a_stamp_within_the_mismatch_of_the_clock_is_on_its_time_base():
    assert same_time_base(NOW - TIME_BASE_MISMATCH_S, NOW)
    assert not same_time_base(NOW - TIME_BASE_MISMATCH_S - 1.0, NOW)
    assert not same_time_base(NOW, 0.0)                 # no /clock yet under use_sim_time


def test_each_other_time_base_is_warned_of_once():
    # Stamps 2 h behind the clock, then 2 h ahead of it (a second publisher on another
    # clock): the second time base was not reported, as only the first stamp of all was.
    warnings = []
    check = TimeBaseCheck(warnings.append)
    assert check(NOW, NOW)
    assert not check(NOW - 7200.0, NOW)
    assert not check(NOW - 7190.0, NOW)                 # the same time base: no new warning
    assert not check(NOW + 7200.0, NOW)
    assert not check(NOW + 7300.0, NOW)
    assert not check(5.0, 0.0)                          # no clock yet: not warned of
    assert len(warnings) == 2
    assert warnings[0].startswith('stamps are -7200 s from the node clock')
    assert warnings[1].startswith('stamps are 7200 s from the node clock')
    # Live (a tracker stamping with its camera's clock from 0), the fix is the stamps', not
    # a /clock (a walk-through, 7 Dec 2026): both are said.
    assert 'live, stamp in ROS time' in warnings[0] and 'replayed, run with use_sim_time' \
        in warnings[0]


def test_stamps_scattered_over_hours_warn_a_bounded_number_of_times():
    # A clock sending garbage: stamps hours apart, each on a time base of its own. Each of
    # the first MAX_TIME_BASES is told once, then one line says no more are, and none is
    # kept beyond those (the check's memory does not grow with the garbage).
    from tt_ros.timebase import MAX_TIME_BASES
    warnings = []
    check = TimeBaseCheck(warnings.append)
    for hours in range(2, 500):
        assert not check(NOW + hours * 2.5 * TIME_BASE_MISMATCH_S, NOW)
    assert len(warnings) == MAX_TIME_BASES + 1
    assert all(w.startswith('stamps are ') for w in warnings[:-1])
    assert warnings[-1].startswith(f'stamps on more than {MAX_TIME_BASES} other time bases')
    assert len(check.warned) == MAX_TIME_BASES
    assert check(NOW + 1.0, NOW)                        # the clock's own still pass


def test_messages_under_sim_time_with_no_clock_are_warned_of_once_when_it_lasts():
    # use_sim_time on a live graph, no /clock: every time check was off without a word (a
    # ROS user's walk-through). A replay's first messages before its first /clock are not.
    from tt_ros.timebase import NO_CLOCK_S, NO_CLOCK_WARNING
    wall = [100.0]
    warnings = []
    check = TimeBaseCheck(warnings.append, monotonic=lambda: wall[0])
    for dt in (0.0, 0.5, NO_CLOCK_S - 0.01):
        wall[0] = 100.0 + dt
        assert not check(NOW + dt, 0.0)
    assert warnings == []
    for dt in (NO_CLOCK_S, NO_CLOCK_S + 5.0):
        wall[0] = 100.0 + dt
        assert not check(NOW + dt, 0.0)
    assert warnings == [NO_CLOCK_WARNING]
    assert check(NOW, NOW)                              # once a clock has come
