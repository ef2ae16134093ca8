"""tt_ros.ratelimit: stamp-paced work and throttled log lines."""

from tt_ros.ratelimit import ThrottledLog, due


def test_work_is_due_once_a_period_of_the_stamps_and_again_when_they_go_back():
    assert due(5, None, 10.0)
    assert not due(10**8 - 1, 0, 10.0)         # 10 Hz: 100 ms apart
    assert due(10**8, 0, 10.0)
    assert due(0, 10**9, 10.0)                 # a replay restarting
    assert due(1, 0, 0.0)                      # no limit


def test_a_throttled_line_goes_out_first_then_once_a_period_per_kind():
    now = [100.0]
    lines = []
    log = ThrottledLog(lines.append, clock=lambda: now[0])
    assert log('drop', 1.0, 'a')
    now[0] += 0.75
    assert not log('drop', 1.0, 'b')           # within the period of the first
    assert log('late', 5.0, 'c')               # another kind has its own period
    now[0] += 0.5
    assert log('drop', 1.0, 'd')               # a period after the last one out
    now[0] += 4.0
    assert not log('late', 5.0, 'e')
    assert lines == ['a', 'c', 'd']
