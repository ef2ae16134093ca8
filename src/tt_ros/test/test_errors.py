import errno

from tt_ros.errors import one_line_reason
import yaml


def test_a_yaml_error_gives_its_first_line():
    try:
        yaml.safe_load('version: [garbage\n')
    except yaml.YAMLError as exc:
        assert '\n' in str(exc)             # the parser's text spans several lines
        assert one_line_reason(exc) == str(exc).splitlines()[0].strip()


def test_an_os_error_gives_its_strerror():
    exc = FileNotFoundError(errno.ENOENT, 'No such file or directory', 'x.yaml')
    assert one_line_reason(exc) == 'No such file or directory'


def test_an_error_without_text_gives_its_type():
    assert one_line_reason(KeyError()) == 'KeyError'
    assert one_line_reason(ValueError('\n  \nsecond line')) == 'second line'
