"""One-line reasons of errors, for the tools' and nodes' one-line messages (no rclpy)."""


def one_line_reason(exc):
    """The one-line reason of the error ``exc``: an OSError's strerror; a YAML parser's
    problem and its line (its text spans several lines, the first only the context: 'while
    parsing a flow sequence'); else the first non-blank line of its text, else its type's
    name."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    problem, mark = getattr(exc, 'problem', None), getattr(exc, 'problem_mark', None)
    if isinstance(problem, str) and problem:
        return f'{problem} (line {mark.line + 1})' if mark is not None else problem
    for line in str(exc).splitlines():
        if line.strip():
            return line.strip()
    return type(exc).__name__
