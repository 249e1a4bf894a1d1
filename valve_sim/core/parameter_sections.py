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
Which sections of ROS 2 parameter files apply to a node, and what they set, as rcl decides.

A parameter file maps node names to `ros__parameters:`. This module takes the parsed
YAML documents (reading the bytes is valve_sim.core.parameters' job) and mirrors, for the
offline tools and for valve_node's log, what ROS 2 Jazzy does with them
(rcl_yaml_param_parser/src/parse.c builds the names; rclpy/src/rclpy/node.cpp,
_populate_node_parameters_from_rcl_params, matches them):

- Section names: the keys above `ros__parameters` (any key that starts with it), nested
  keys joined with '/' (`rig1: {relief_valve: {ros__parameters: ...}}` is
  `rig1/relief_valve`); a name without a leading '/' gets one (`relief_valve` is
  `/relief_valve`). Parameters below are flattened with '.' (`fault: {x: 1}` is `fault.x`).
- Matching: the name is a pattern for the node's fully qualified name, `/*` standing for
  one name token and `/**` for any number (none included); the whole name must match.
  For the node /rig1/relief_valve: `/**`, `/**/relief_valve`, `/*/relief_valve` and
  `/rig1/relief_valve` apply; `relief_valve` (= `/relief_valve`) applies only to a node
  in the root namespace.
- Merging: all files of one command line are parsed into one table of sections, in the
  order each section name first appears (across the files, in their order); a section
  name seen again adds to its first appearance and its later values win. The sections
  that apply are then merged in that table's order, a later section's value winning.
  So within one file the later section wins; across files a later file wins for a
  section it repeats, and its new sections come after every section already seen.
"""

from dataclasses import dataclass, field
import re

from valve_sim.core.errors import SectionError

PARAMS_KEY = 'ros__parameters'
_TOKEN = re.compile(r'[A-Za-z_][A-Za-z0-9_]*')


@dataclass
class Sections:
    """What the files hold for one node: the merged parameters and which sections gave them."""

    parameters: dict = field(default_factory=dict)  # {dotted name: value}
    applied: list = field(default_factory=list)  # [(source, section name)] in merge order
    not_applied: list = field(default_factory=list)  # [(source, section)] naming the node


def node_sections(document, source='parameter file'):
    """
    Return [(section name, {dotted parameter name: value})] of one parsed file, in file order.

    document: the parsed YAML (a mapping). Names are as rcl forms them, with a leading
    '/'. Raises SectionError for a file that is not node names over ros__parameters.
    """
    if not isinstance(document, dict):
        raise SectionError(f"{source} must map node names to '{PARAMS_KEY}'")
    sections = []
    _collect(document, '', source, sections)
    return sections


def _collect(mapping, prefix, source, sections):
    for key, value in mapping.items():
        key = str(key)
        if key.startswith(PARAMS_KEY):
            if not prefix:
                raise SectionError(f"{source}: '{key}' has no node name above it")
            if not isinstance(value, dict):
                raise SectionError(f"{source}: '{prefix}: {key}:' must be a mapping")
            name = prefix if prefix.startswith('/') else '/' + prefix
            check_section_name(name, source)
            sections.append((name, _flattened(value)))
        elif isinstance(value, dict):
            joined = key if not prefix else prefix + ('' if prefix.endswith('/') else '/') + key
            _collect(value, joined, source, sections)
        else:
            raise SectionError(
                f"{source}: '{prefix + '/' if prefix else ''}{key}' is neither a node name "
                f"over '{PARAMS_KEY}:' nor inside one"
            )


def _flattened(raw, prefix=''):
    flat = {}
    for key, value in raw.items():
        if isinstance(value, dict):
            flat.update(_flattened(value, f'{prefix}{key}.'))
        else:
            flat[f'{prefix}{key}'] = value
    return flat


def check_section_name(name, source='parameter file'):
    """Raise SectionError unless name is a node name (or pattern) rcl accepts."""
    if name in ('/**', '/*'):
        return
    tokens = name[1:].split('/')
    if not all(token in ('*', '**') or _TOKEN.fullmatch(token) for token in tokens):
        raise SectionError(
            f"{source}: section '{name}' is not a node name: names and namespaces are "
            "letters, digits and '_' (not first a digit), '/' between them, '*' or '**' "
            'as wildcards (rcl refuses such a file)'
        )


def section_applies(name, node_fqn):
    """Whether a section name (leading '/') applies to the node node_fqn, as rclpy matches."""
    pattern = name.replace('/*', r'(/\w+)')  # '/**' becomes '(/\w+)*', as rclpy replaces
    return re.fullmatch(pattern, node_fqn, flags=re.ASCII) is not None


def names_node(name, node_name):
    """Whether a section name ends in the node's own name (a section meant for it)."""
    return name.rsplit('/', 1)[-1] == node_name


def parameters_for_node(files, node_fqn):
    """
    Merge what files [(source, parsed document)], in command-line order, set for node_fqn.

    Returns Sections: the merged {dotted name: value}, the (source, section) pairs that
    apply in merge order, and those that name the node (their last name is its name)
    without applying to it, e.g. 'relief_valve' for /rig1/relief_valve.
    """
    table, where = {}, {}  # section name -> merged parameters / sources, first appearance first
    for source, document in files:
        for name, values in node_sections(document, source):
            table.setdefault(name, {}).update(values)
            where.setdefault(name, []).append(source)
    node_name = node_fqn.rsplit('/', 1)[-1]
    result = Sections()
    for name, values in table.items():
        if section_applies(name, node_fqn):
            result.parameters.update(values)
            result.applied += [(source, name) for source in where[name]]
        elif names_node(name, node_name):
            result.not_applied += [(source, name) for source in where[name]]
    return result


def node_fqn(namespace, node_name):
    """Fully qualified node name of node_name in namespace ('' or '/' is the root)."""
    namespace = '/' + namespace.strip('/') if namespace.strip('/') else ''
    return f'{namespace}/{node_name}'


def describe_not_applied(sections, node_fqn):
    """One sentence on sections meant for the node that do not apply to it, or ''."""
    if not sections.not_applied:
        return ''
    named = ', '.join(f"'{name}' ({source})" for source, name in sections.not_applied)
    node_name = node_fqn.rsplit('/', 1)[-1]
    return (
        f'section(s) {named} name {node_name} but do not apply to {node_fqn} '
        f"(a name without a namespace means the root namespace); '/**/{node_name}:' applies "
        'in every namespace'
    )
