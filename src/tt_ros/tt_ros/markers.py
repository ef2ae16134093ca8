"""RViz markers on /tt/markers, shared by the nodes (ROS glue: imports visualization_msgs)."""

from visualization_msgs.msg import Marker

LIFETIME_NS = 500_000_000
"""How long a marker stays without an update, ns."""


def add_marker(markers, header, ns, mid, kind, rgb, scale, alpha=1.0):
    """Append to the MarkerArray ``markers`` a marker of ``kind`` (Marker.SPHERE, ...) with id
    ``mid`` in namespace ``ns``, stamped and framed as ``header`` (frame 'table' if empty),
    colour ``rgb`` (0..1) and ``alpha``, and ``scale`` (m: one number for all axes or three);
    identity orientation. Returns it for the caller to place."""
    m = Marker()
    m.header.stamp = header.stamp
    m.header.frame_id = header.frame_id or 'table'
    m.ns = ns
    m.id = mid
    m.type = kind
    m.action = Marker.ADD
    m.pose.orientation.w = 1.0
    sx, sy, sz = (scale,) * 3 if isinstance(scale, (int, float)) else scale
    m.scale.x, m.scale.y, m.scale.z = float(sx), float(sy), float(sz)
    m.color.r, m.color.g, m.color.b = rgb
    m.color.a = alpha
    m.lifetime.nanosec = LIFETIME_NS
    markers.markers.append(m)
    return m
