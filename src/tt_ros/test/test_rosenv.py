"""ROS_DOMAIN_ID checked before rcl reads it: the values rcl and Fast DDS mishandle refused.

What they do with each (rclpy 7.1.6, Fast DDS, measured 2 Dec 2026): 'abc' an RCLError at
init; '233' ends the process inside Fast DDS at the first node (ports past 65535); '1e2'
taken as domain 1, '0x10' as 16, '-5' as 18446744073709551611."""

import pytest
from tt_ros.rosenv import DOMAIN_ID_MAX, domain_id_error


@pytest.mark.parametrize('value', [None, '', '  ', '0', '7', ' 5', '5 ', '101', '232'])
def test_a_domain_id_rcl_and_fast_dds_take_as_written_passes(value):
    environ = {} if value is None else {'ROS_DOMAIN_ID': value}
    assert domain_id_error(environ) is None


@pytest.mark.parametrize('value', ['abc', '1e2', '0x10', '-5', '-1', '+3', '3.0', '٣'])
def test_a_value_rcl_misreads_is_named(value):
    error = domain_id_error({'ROS_DOMAIN_ID': value})
    assert error.startswith(f"ROS_DOMAIN_ID '{value.strip()}' is not a domain id"), error
    assert '\n' not in error


@pytest.mark.parametrize('value', [DOMAIN_ID_MAX + 1, 1000, 10 ** 20])
def test_a_domain_without_ports_is_out_of_range(value):
    error = domain_id_error({'ROS_DOMAIN_ID': str(value)})
    assert error.startswith(f'ROS_DOMAIN_ID {value} is out of range'), error
    assert f'0-{DOMAIN_ID_MAX}' in error
