"""tt_ros.messages: which headers the nodes drop, and why."""

from std_msgs.msg import Header
from tt_ros.messages import UNSTAMPED, stamp_ns
from tt_ros.messages import header_problem as problem


def header_problem(header, **kwargs):
    """What a node asks of a message's header (its stamp in ns, as it has it already)."""
    return problem(stamp_ns(header.stamp), header.frame_id, **kwargs)


def _header(sec, nanosec, frame_id):
    h = Header(frame_id=frame_id)
    h.stamp.sec, h.stamp.nanosec = sec, nanosec
    return h


def test_a_header_stamped_zero_or_in_another_frame_is_dropped_with_its_reason():
    assert header_problem(_header(0, 0, 'table')) == UNSTAMPED
    assert header_problem(_header(0, 1, 'table')) is None          # 1 ns is a stamp
    assert header_problem(_header(12, 0, 'table')) is None
    assert header_problem(_header(12, 0, '')) is None              # empty: the table's
    assert header_problem(_header(12, 0, 'world')) == "frame 'world' is not 'table'"
    assert header_problem(_header(12, 0, 'table'), frame='map') == "frame 'table' is not 'map'"
