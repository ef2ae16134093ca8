"""Whether a name can be a ROS topic's or node's full name (rcl's rules, through rclpy)."""

from rclpy.exceptions import InvalidTopicNameException
from rclpy.validate_full_topic_name import validate_full_topic_name


def name_error(name):
    """Why ``name`` (made absolute: a leading '/' added) is no valid full topic or node name,
    in a few words, or ''. rclpy's own message is three lines (what, the name, a caret)."""
    try:
        validate_full_topic_name(name if name.startswith('/') else '/' + name)
    except InvalidTopicNameException as exc:
        first = str(exc).splitlines()[0].split(': ', 1)[-1].rstrip(':')
        return first.replace('topic name ', 'a name ')
    return ''
