"""Small pieces shared by the tt nodes (ROS glue: imports geometry_msgs): message fields from
arrays, and rate limits by the messages' stamps."""

from geometry_msgs.msg import Point


def point_msg(p):
    """geometry_msgs/Point of ``p`` (x, y[, z]), m; z 0 for a point on the table (2 numbers)."""
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]) if len(p) > 2 else 0.0)


def set_xyz(msg, v):
    """Set the x, y, z of a Point or Vector3 ``msg`` (kept, not replaced) from ``v``."""
    msg.x, msg.y, msg.z = float(v[0]), float(v[1]), float(v[2])


def due(now_ns, last_ns, rate_hz):
    """Whether work limited to ``rate_hz`` (0: no limit) may run at stamp ``now_ns``, last run
    at ``last_ns`` (None: never); a stamp going back (a replayed bag restarting) counts as due."""
    return (rate_hz <= 0.0 or last_ns is None or now_ns < last_ns
            or now_ns - last_ns >= 1e9 / rate_hz)
