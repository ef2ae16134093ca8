"""docs/DEVELOPING.md's checklists 'adding a node parameter' and 'adding a camera source': a
step forgotten fails here (the model-effect checklist has its own test in tt_prediction)."""

import pathlib
import re

import pytest
import yaml

ROOT = pathlib.Path(__file__).resolve().parents[1]

NODES = [  # (node module, its package's parameter file, its docs page)
    ('tt_perception.node', 'src/tt_perception/config/perception.yaml', 'docs/perception.md'),
    ('tt_prediction.node', 'src/tt_prediction/config/prediction.yaml', 'docs/prediction.md'),
    ('tt_strike.node', 'src/tt_strike/config/strike.yaml', 'docs/strike.md'),
]


def _yaml_parameters(path):
    data = yaml.safe_load((ROOT / path).read_text())
    (node,) = data.values()
    return node['ros__parameters']


@pytest.mark.parametrize('module, config, page', NODES, ids=[n[0] for n in NODES])
def test_every_node_parameter_is_in_its_config_file_and_docs(module, config, page):
    node = pytest.importorskip(module)
    declared = {p.name: p for p in node.PARAMETERS}
    in_file = _yaml_parameters(config)
    docs = (ROOT / page).read_text()
    assert sorted(set(declared) - set(in_file)) == [], f'missing from {config}'
    assert sorted(set(in_file) - set(declared)) == [], f'{config} names undeclared parameters'
    assert [n for n in declared if f'`{n}`' not in docs] == [], f'missing from {page}'
    from tt_ros.parameters import coerce
    for name, p in declared.items():     # the shipped file's value is one the node accepts
        assert p.description, name
        coerce(p, in_file[name])         # its type, range or choices (ParameterError)


def test_every_camera_source_kind_is_documented_tested_and_opened():
    from tt_perception.sources import SOURCE_KINDS, source_kind
    docs = (ROOT / 'docs/perception.md').read_text()
    rows = re.findall(r'^\| `([^`]+)`[^|]*\| (.+) \|$', docs, flags=re.M)
    documented = {source_kind(example) for example, text in rows
                  if any(w in text for w in ('V4L2', 'video file', 'image topic'))}
    assert documented == set(SOURCE_KINDS)
    tests = (ROOT / 'src/tt_perception/test/test_sources.py').read_text()
    node = (ROOT / 'src/tt_perception/tt_perception/node.py').read_text()
    for kind in SOURCE_KINDS:
        assert f"'{kind}')" in tests, f'no source_kind example of {kind} in test_sources.py'
        assert f"kind == '{kind}'" in node or kind == 'file', f'perception_node opens {kind}?'
