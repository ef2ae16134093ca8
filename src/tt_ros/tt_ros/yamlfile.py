"""YAML of tt's own files (model.yaml, rigs, workspaces, filter settings), no rclpy.

PyYAML's ``safe_load`` keeps the last of two values given to one key, without a word: a
model.yaml with ``c_d`` twice ran with the second. :func:`load_yaml` refuses it, and reads
YAML 1.2's floats without a dot (``3e-3``) as numbers.
"""

import re

import yaml


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader whose mappings refuse a key given twice."""


def _unique_mapping(loader, node, deep=False):
    seen = set()
    for key_node, _ in node.value:
        if key_node.tag == 'tag:yaml.org,2002:merge':
            continue                    # '<<: *base': its keys may be given again here
        key = loader.construct_object(key_node, deep=deep)
        try:
            twice = key in seen
            seen.add(key)
        except TypeError:           # an unhashable key: construct_mapping names it
            break
        if twice:
            raise yaml.constructor.ConstructorError(
                None, None, f'the key {key!r} is given twice', key_node.start_mark)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)
# YAML 1.2's floats without a dot (3e-3, 1e+20, 2E0), which PyYAML (YAML 1.1) reads as
# strings: a model.yaml's 'mass: 3e-3' was refused as not a number, and ruamel.yaml writes
# such numbers (a walk-through, 6 Dec 2026). The loader's own copy of the resolvers.
_UniqueKeyLoader.yaml_implicit_resolvers = {
    first: list(resolvers) for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_UniqueKeyLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float', re.compile(r'^[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+$'),
    list('-+0123456789.'))


def load_yaml(stream):
    """``yaml.safe_load`` that raises a yaml.YAMLError for a key given twice in a mapping
    (its problem names the key, its mark the line of the second)."""
    return yaml.load(stream, Loader=_UniqueKeyLoader)      # noqa: S506 (a SafeLoader)
