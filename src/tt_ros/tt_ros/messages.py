"""Message fields from numbers and arrays, shared by the tt nodes (ROS glue: imports
geometry_msgs)."""

from geometry_msgs.msg import Point

NS_PER_S = 1_000_000_000

UNSTAMPED = "header.stamp is 0: not set (ros2 topic pub: '{header: {stamp: now}, ...}')"
"""Why prediction_node and strike_node drop a message stamped 0. Taken for another time base,
it only switched their time checks off (stale, too late): a state published without a stamp
on the robot's wall clock got strike commands for 1970. perception_node on video time (from 0)
publishes a track from its third frame on; a bag of ``tt-perceive --out-bag`` may hold a
track's seed frame at 0, which is then dropped."""


def header_problem(stamp, frame_id, frame='table'):
    """Why a message is dropped, or None, from its header's stamp (ns, :func:`stamp_ns`, which
    the nodes have already) and ``frame_id``: stamped 0 (:data:`UNSTAMPED`), or in another
    frame than ``frame`` (an empty frame_id is taken for it)."""
    if stamp == 0:
        return UNSTAMPED
    if frame_id not in ('', frame):
        return f"frame '{frame_id}' is not '{frame}'"
    return None


def point_msg(p):
    """geometry_msgs/Point of ``p`` (x, y[, z]), m; z 0 for a point on the table (2 numbers)."""
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]) if len(p) > 2 else 0.0)


def set_xyz(msg, v):
    """Set the x, y, z of a Point or Vector3 ``msg`` (kept, not replaced) from ``v``."""
    msg.x, msg.y, msg.z = float(v[0]), float(v[1]), float(v[2])


def set_time(msg, ns):
    """Set a builtin_interfaces/Time ``msg`` (sec, nanosec) to ``ns`` nanoseconds (int)."""
    msg.sec, msg.nanosec = int(ns // NS_PER_S), int(ns % NS_PER_S)


def stamp_ns(stamp):
    """Nanoseconds (int) of a builtin_interfaces/Time ``stamp``."""
    return stamp.sec * NS_PER_S + stamp.nanosec


def seconds_text(ns):
    """A time in ns (int) as seconds, every digit kept (a float keeps 0.1 us at today's
    epoch): '1700000000.000000001'."""
    return f'{ns // NS_PER_S}.{ns % NS_PER_S:09d}'
