"""One-line reasons of errors, for the tools' and nodes' one-line messages (no rclpy)."""


def one_line_reason(exc):
    """The one-line reason of the error ``exc``: an OSError's strerror, else the first
    non-blank line of its text (a YAML parser's spans several lines, with a caret under the
    place), else its type's name."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    for line in str(exc).splitlines():
        if line.strip():
            return line.strip()
    return type(exc).__name__
