"""YAML of tt's own files (model.yaml, rigs, workspaces, filter settings), no rclpy.

PyYAML's ``safe_load`` keeps the last of two values given to one key, without a word: a
model.yaml with ``c_d`` twice ran with the second. :func:`load_yaml` refuses it.
"""

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


def load_yaml(stream):
    """``yaml.safe_load`` that raises a yaml.YAMLError for a key given twice in a mapping
    (its problem names the key, its mark the line of the second)."""
    return yaml.load(stream, Loader=_UniqueKeyLoader)      # noqa: S506 (a SafeLoader)
