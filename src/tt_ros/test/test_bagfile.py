"""Message definitions for bags: from rosbags' Jazzy store or from installed .msg files."""

import pytest
from tt_ros.bagfile import BagError, TypeRegistry


def _install_msgs(prefix, package, msgs):
    marker = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / package
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.write_text('')
    (prefix / 'share' / package / 'msg').mkdir(parents=True)
    for name, text in msgs.items():
        (prefix / 'share' / package / 'msg' / f'{name}.msg').write_text(text)


def test_custom_types_are_read_from_installed_msg_files_recursively(tmp_path):
    _install_msgs(tmp_path, 'rig_msgs', {
        'Rig': 'std_msgs/Header header\nrig_msgs/Camera[] cameras\n',
        'Camera': '# one camera\nstring name\nfloat64[9] k\ngeometry_msgs/Pose pose\n',
    })
    registry = TypeRegistry(str(tmp_path))
    msgdef, digest = registry.definition('rig_msgs/msg/Rig')
    # The stored definition holds the type and, after separators, every type it uses.
    assert msgdef.startswith('std_msgs/Header header\nrig_msgs/Camera[] cameras')
    for used in ('MSG: rig_msgs/Camera', 'MSG: std_msgs/Header', 'MSG: geometry_msgs/Pose'):
        assert used in msgdef
    assert digest.startswith('RIHS01_') and len(digest) == len('RIHS01_') + 64
    # A change of the definition changes the hash.
    other = tmp_path / 'other'
    _install_msgs(other, 'rig_msgs', {
        'Rig': 'std_msgs/Header header\nrig_msgs/Camera[] cameras\n',
        'Camera': 'string name\nfloat32[9] k\ngeometry_msgs/Pose pose\n',
    })
    assert TypeRegistry(str(other)).definition('rig_msgs/msg/Rig')[1] != digest


def test_standard_types_need_no_msg_file(tmp_path):
    msgdef, _ = TypeRegistry(str(tmp_path)).definition('sensor_msgs/msg/CameraInfo')
    assert msgdef.splitlines()[:6] == ['std_msgs/Header header', 'uint32 height', 'uint32 width',
                                       'string distortion_model', 'float64[] d', 'float64[9] k']
    assert 'MSG: sensor_msgs/RegionOfInterest' in msgdef


def test_a_type_without_definition_is_a_one_line_error(tmp_path):
    _install_msgs(tmp_path, 'rig_msgs', {'Rig': 'rig_msgs/Missing part\n'})
    with pytest.raises(BagError, match="no message definition found for 'rig_msgs/msg/Missing'"):
        TypeRegistry(str(tmp_path)).definition('rig_msgs/msg/Rig')
