import pytest
from tt_ros.errors import one_line_reason
from tt_ros.yamlfile import load_yaml
import yaml


def test_a_key_given_twice_is_refused_with_its_line():
    text = 'ball:\n  c_d: 0.5\n  mu: 0.2\n  c_d: 0.4\n'
    assert yaml.safe_load(text)['ball']['c_d'] == 0.4       # PyYAML keeps the last, silently
    with pytest.raises(yaml.YAMLError) as err:
        load_yaml(text)
    assert one_line_reason(err.value) == "the key 'c_d' is given twice (line 4)"


def test_it_reads_what_safe_load_reads():
    text = 'a: [1, 2.5, {b: x}]\nc: {d: null, e: true}\nf: 1.0e-3\ng: 0x10\nh: e3\n'
    assert load_yaml(text) == yaml.safe_load(text)
    assert load_yaml('') is None
    # The same key in two mappings is not one given twice.
    assert load_yaml('a: {k: 1}\nb: {k: 2}\n') == {'a': {'k': 1}, 'b': {'k': 2}}


def test_yaml_1_2_floats_without_a_dot_are_numbers():
    # PyYAML (YAML 1.1) reads 3e-3 as a string: a model.yaml's 'mass: 3e-3' was refused as
    # not a number, and ruamel.yaml writes 1e+20 (a walk-through, 6 Dec 2026).
    text = 'a: 3e-3\nb: 1e+20\nc: -2E0\nd: .5e3\ne: 1e\nf: "3e-3"\n'
    assert yaml.safe_load(text)['a'] == '3e-3'
    assert load_yaml(text) == {'a': 0.003, 'b': 1e20, 'c': -2.0, 'd': 500.0, 'e': '1e',
                               'f': '3e-3'}
    assert yaml.safe_load('a: 3e-3\n') == {'a': '3e-3'}      # PyYAML's own loader as it was


def test_it_constructs_only_what_safe_load_does():
    with pytest.raises(yaml.YAMLError):
        load_yaml('!!python/object/apply:os.system ["true"]\n')


def test_merge_keys_read_as_safe_load_reads_them():
    # '<<: *base' failed ('could not determine a constructor ... merge'): a review.
    text = ('base: &b {c_d: 0.5, mu: 0.2}\n'
            'one: {<<: *b, c_d: 0.4}\n'
            'two: {<<: [*b, {e_t: 0.9}]}\n')
    assert load_yaml(text) == yaml.safe_load(text)
    assert load_yaml(text)['one'] == {'c_d': 0.4, 'mu': 0.2}
    with pytest.raises(yaml.YAMLError):
        load_yaml('one: {<<: {a: 1}, c_d: 0.4, c_d: 0.3}\n')
