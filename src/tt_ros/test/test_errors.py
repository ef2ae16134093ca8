import errno

import pytest
from tt_ros.errors import one_line_reason
import yaml


def test_a_yaml_error_gives_its_problem_and_line():
    # The first line of PyYAML's text is only the context ('while parsing a flow sequence').
    with pytest.raises(yaml.YAMLError) as err:
        yaml.safe_load('version: [garbage\n')
    assert '\n' in str(err.value)                  # the parser's text spans several lines
    assert one_line_reason(err.value) == "expected ',' or ']', but got '<stream end>' (line 2)"


def test_an_os_error_gives_its_strerror():
    exc = FileNotFoundError(errno.ENOENT, 'No such file or directory', 'x.yaml')
    assert one_line_reason(exc) == 'No such file or directory'


def test_an_error_without_text_gives_its_type():
    assert one_line_reason(KeyError()) == 'KeyError'
    assert one_line_reason(ValueError('\n  \nsecond line')) == 'second line'
