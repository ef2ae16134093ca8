"""Checks of the ROS environment variables before rclpy starts (no rclpy import).

rcl and Fast DDS read ``ROS_DOMAIN_ID`` loosely: ``abc`` is an RCLError traceback at
``rclpy.init``, ``233`` or more ends the process inside Fast DDS when the first node is
created (its ports would pass 65535), and ``1e2`` is taken as 1, ``-5`` as
18446744073709551611. Every tt node and command checks it first and refuses such a value in
one line.
"""

import os

DOMAIN_ID_MAX = 232
"""Largest domain id Fast DDS can give ports to (7400 + 250 x domain + offsets <= 65535)."""
DOMAIN_ID_SAFE_MAX = 101
"""Largest domain id whose ports stay below Linux's ephemeral port range (32768-60999): a
larger one can collide with ports the system hands out (the ROS 2 docs, "The ROS_DOMAIN_ID")."""


def domain_id_error(environ=None):
    """One line saying what is wrong with ``ROS_DOMAIN_ID`` in ``environ`` (None:
    ``os.environ``), or None when it is unset, empty or a whole number 0-232."""
    value = (os.environ if environ is None else environ).get('ROS_DOMAIN_ID', '').strip()
    if not value:
        return None
    if not value.isdigit() or not value.isascii():
        return (f"ROS_DOMAIN_ID '{value}' is not a domain id: a whole number "
                f'0-{DOMAIN_ID_MAX}, or unset for 0')
    if int(value) > DOMAIN_ID_MAX:
        return (f'ROS_DOMAIN_ID {int(value)} is out of range: Fast DDS has ports for '
                f'0-{DOMAIN_ID_MAX} only ({DOMAIN_ID_SAFE_MAX} at most keeps them clear of '
                "Linux's ephemeral ports)")
    return None
