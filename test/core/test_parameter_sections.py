# Copyright 2026 valve_sim developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
Which sections of parameter files apply to valve_node, offline as rcl decides it live.

Each case is checked against rclpy itself: a node of that name and namespace is
created in this process with the files as --params-file arguments, and the
parameter overrides rcl hands it must equal what valve_sim.core.parameter_sections
merges offline.
"""

import pytest
from valve_sim.core.errors import ParameterError, SectionError
from valve_sim.core.parameter_sections import node_fqn, parameters_for_node, section_applies
from valve_sim.core.parameters import load_parameters, parameter_document


FILES = {
    'plain': 'relief_valve:\n  ros__parameters:\n    a: 1.0\n    b: 1.0\n',
    'slash': '/relief_valve:\n  ros__parameters:\n    a: 2.0\n',
    'any_node': '/**:\n  ros__parameters:\n    a: 3.0\n    c: 3.0\n',
    'any_namespace': '/**/relief_valve:\n  ros__parameters:\n    a: 4.0\n    d: 4.0\n',
    'rig1': '/rig1/relief_valve:\n  ros__parameters:\n    a: 5.0\n',
    'nested_rig1': 'rig1:\n  relief_valve:\n    ros__parameters:\n      a: 6.0\n      e: 6.0\n',
    'one_token': '/*/relief_valve:\n  ros__parameters:\n    a: 7.0\n',
    'other_node': 'valve_analyser:\n  ros__parameters:\n    a: 8.0\n',
    # later sections win inside a file; /** comes after relief_valve here
    'ordered': (
        'relief_valve:\n  ros__parameters:\n    a: 9.0\n    f: 9.0\n'
        '/**:\n  ros__parameters:\n    a: 10.0\n'
    ),
    'nested_values': '/**/relief_valve:\n  ros__parameters:\n    fault:\n      x: 11.0\n',
}
CASES = [
    (['plain'], '/'),
    (['plain'], '/rig1'),
    (['slash', 'plain'], '/'),
    (['any_node', 'plain'], '/'),
    (['plain', 'any_node'], '/'),
    (['any_namespace'], '/rig1'),
    (['any_namespace'], '/'),
    (['any_namespace'], '/a/b'),
    (['rig1', 'plain', 'any_node', 'any_namespace'], '/rig1'),
    (['rig1'], '/rig2'),
    (['nested_rig1', 'rig1'], '/rig1'),
    (['one_token'], '/rig1'),
    (['one_token'], '/a/b'),
    (['one_token'], '/'),
    (['other_node', 'any_node'], '/'),
    (['ordered'], '/'),
    # across files: /** first seen in the first file keeps that place in the merge
    (['any_node', 'rig1', 'ordered'], '/'),
    (['ordered', 'plain'], '/'),
    (['nested_values', 'any_node'], '/x'),
]


def rcl_overrides(paths, namespace):
    """Return the parameter overrides rclpy gives node relief_valve in namespace from paths."""
    import rclpy

    context = rclpy.Context()
    arguments = ['--ros-args'] + [part for path in paths for part in ('--params-file', path)]
    rclpy.init(args=arguments, context=context)
    try:
        node = rclpy.create_node('relief_valve', namespace=namespace, context=context)
        overrides = {name: p.value for name, p in node._parameter_overrides.items()}
        node.destroy_node()
    finally:
        context.try_shutdown()
    return overrides


@pytest.mark.parametrize('names, namespace', CASES, ids=lambda v: str(v))
def test_the_sections_that_apply_are_those_rcl_applies(tmp_path, names, namespace):
    paths = []
    for name in names:
        path = tmp_path / f'{name}.yaml'
        path.write_text(FILES[name])
        paths.append(str(path))
    offline = parameters_for_node(
        [(path, parameter_document(path)) for path in paths], node_fqn(namespace, 'relief_valve')
    )
    assert offline.parameters == rcl_overrides(paths, namespace)


def test_sections_naming_the_node_elsewhere_are_reported():
    files = [('f.yaml', {'relief_valve': {'ros__parameters': {'a': 1.0}},
                         '/**/relief_valve': {'ros__parameters': {'b': 2.0}},
                         '/rig2/relief_valve': {'ros__parameters': {'c': 3.0}},
                         'valve_analyser': {'ros__parameters': {'d': 4.0}}})]
    sections = parameters_for_node(files, '/rig1/relief_valve')
    assert sections.parameters == {'b': 2.0}
    assert sections.applied == [('f.yaml', '/**/relief_valve')]
    assert sections.not_applied == [('f.yaml', '/relief_valve'), ('f.yaml', '/rig2/relief_valve')]


@pytest.mark.parametrize('name, fqn, applies', [
    ('/**', '/relief_valve', True),
    ('/**/relief_valve', '/relief_valve', True),
    ('/**/relief_valve', '/a/b/relief_valve', True),
    ('/**/relief_valve', '/a/other', False),
    ('/relief_valve', '/rig1/relief_valve', False),
    ('/*/relief_valve', '/relief_valve', False),
])
def test_wildcards_match_as_in_rclpy(name, fqn, applies):
    assert section_applies(name, fqn) is applies


@pytest.mark.parametrize('document', [
    {'ros__parameters': {'a': 1}},
    {'relief valve': {'ros__parameters': {'a': 1}}},
    {'relief_valve': 3},
])
def test_files_rcl_refuses_are_refused(document):
    with pytest.raises(SectionError):
        parameters_for_node([('f.yaml', document)], '/relief_valve')


def test_the_offline_tools_take_the_wildcard_and_namespaced_forms(tmp_path, reference):
    path = tmp_path / 'valve.yaml'
    path.write_text('/**/relief_valve:\n  ros__parameters:\n    main_valve_mass: 0.07\n')
    assert load_parameters(path).params['main_valve_mass'] == 0.07
    path.write_text('/rig1/relief_valve:\n  ros__parameters:\n    main_valve_mass: 0.07\n')
    assert load_parameters(path, namespace='/rig1').params['main_valve_mass'] == 0.07
    with pytest.raises(ParameterError, match=r"'/rig1/relief_valve' .* do not apply to "
                       r'/relief_valve'):
        load_parameters(path)
    path.write_text('relief_valve:\n  ros__parameters:\n    main_valve_mass: 0.07\n'
                    '/**:\n  ros__parameters:\n    main_valve_mass: 0.08\n')
    assert load_parameters(path).params['main_valve_mass'] == 0.08  # rcl: the later section wins
