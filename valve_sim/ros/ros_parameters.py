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
ROS 2 parameter declarations for the entries of valve_sim's parameter catalogue.

Turns a ParameterSpec (valve_sim.core.catalogue) into a ParameterDescriptor: the
description carries the symbol, unit and source, and a FloatingPointRange (an
IntegerRange) holds the spec's limits, so `ros2 param describe` tells a user what each
number is. declare() declares an entry of any kind.

Types are lenient: ROS 2 types a parameter-file value 0 as an integer, which a
double parameter would refuse. declare_double() and integers_as_doubles() accept
an integer for a double parameter and store it as a double. value_problem()
explains a bad value with the parameter's symbol, limits and unit (rclpy's own
type refusal names neither the parameter nor the expected unit).

log_parameter_files() says which sections of each --params-file rcl applied to the
node, and warns of sections meant for it (by its name) that apply to another
namespace: rcl ignores those silently (valve_sim.core.parameter_sections).
"""

import difflib
import math

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    ParameterValue,
)
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.parameter import Parameter
from valve_sim.core.errors import ParameterError
from valve_sim.core.parameter_sections import describe_not_applied, parameters_for_node
from valve_sim.core.parameters import parameter_document


def descriptor(spec, read_only=False):
    """Build the ParameterDescriptor of a double parameter from a ParameterSpec."""
    return ParameterDescriptor(
        name=spec.name,
        type=ParameterType.PARAMETER_DOUBLE,
        description=f'{spec.describe()}; source: {spec.source}',
        additional_constraints=(
            f'{spec.minimum:g} <= {spec.symbol} <= {spec.maximum:g} {spec.unit}'
        ),
        read_only=read_only,
        floating_point_range=[
            FloatingPointRange(
                from_value=float(spec.minimum), to_value=float(spec.maximum), step=0.0
            )
        ],
    )


def declare_double(node, spec, default, read_only=False):
    """
    Declare the double parameter of spec on node; returns its value as a float.

    The value is default [spec.unit] unless a parameter file or -p override sets
    it; an integer override (e.g. `main_valve_damping: 0`) is taken as a double.
    Raises rclpy's InvalidParameterValueException / InvalidParameterTypeException
    for a value outside the limits or of another type.
    """
    wanted = descriptor(spec, read_only)
    try:
        return node.declare_parameter(spec.name, float(default), wanted).value
    except InvalidParameterTypeException:
        pass
    # The override has another type: take it untyped, then retype an integer as double.
    untyped = ParameterDescriptor(dynamic_typing=True)
    value = node.declare_parameter(spec.name, float(default), untyped).value
    if isinstance(value, bool) or not isinstance(value, int):
        raise InvalidParameterTypeException(
            Parameter(spec.name, value=value), Parameter.Type.DOUBLE
        )
    node.set_descriptor(
        spec.name,
        wanted,
        ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(value)),
    )
    return float(value)


def declare(node, spec):
    """
    Declare the catalogue entry spec on node with its default; returns the value.

    A double goes through declare_double; a switch, an integer (with its range) and a
    string are declared as their type. Read-only unless spec.live.
    """
    if spec.kind == 'double':
        return declare_double(node, spec, spec.default, not spec.live)
    kinds = {  # type, description
        'bool': (ParameterType.PARAMETER_BOOL, f'{spec.describe()}; source: {spec.source}'),
        'integer': (ParameterType.PARAMETER_INTEGER, f'{spec.description}; source: {spec.source}'),
        'string': (ParameterType.PARAMETER_STRING, spec.description),
    }
    kind, description = kinds[spec.kind]
    wanted = ParameterDescriptor(
        name=spec.name, type=kind, description=description, read_only=not spec.live
    )
    if spec.kind == 'integer':
        wanted.integer_range = [
            IntegerRange(from_value=int(spec.minimum), to_value=int(spec.maximum), step=1)
        ]
    return node.declare_parameter(spec.name, spec.default, wanted).value


def integers_as_doubles(parameters, double_names):
    """Copy a list of rclpy Parameters with integer values of double_names turned into doubles."""
    return [
        Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
        if p.name in double_names and p.type_ == Parameter.Type.INTEGER
        else p
        for p in parameters
    ]


def value_problem(spec, parameter):
    """
    Explain why the rclpy Parameter is no valid value for spec, or return None.

    The explanation names the parameter, the limit and the unit.
    """
    label = f"parameter '{spec.name}' ({spec.symbol})"
    if parameter.type_ not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER):
        return (
            f'{label} must be a number in {spec.unit}, '
            f'got {parameter.type_.name.lower()} {parameter.value!r}'
        )
    value = float(parameter.value)
    if not math.isfinite(value):
        return f'{label} must be finite, got {value}'
    if not spec.minimum <= value <= spec.maximum:
        return (
            f'{label} = {value:g} {spec.unit} is outside its limits '
            f'[{spec.minimum:g}, {spec.maximum:g}] {spec.unit}'
        )
    return None


def undeclared_reason(name, specs):
    """
    Explain that name is no parameter of the node; suggest the declared one meant.

    specs: {declared name: ParameterSpec}. A paper symbol (m_m) gets its parameter's
    name (main_valve_mass); anything else the closest declared name, if one is close.
    """
    reason = f"parameter '{name}' is not declared by this node"
    by_symbol = {spec.symbol: spec.name for spec in specs.values()}
    if name in by_symbol:
        return f"{reason}; '{name}' is the paper's symbol of '{by_symbol[name]}': set that"
    close = difflib.get_close_matches(name, list(specs), n=1)
    return f"{reason}; did you mean '{close[0]}'?" if close else reason


def parameter_file_arguments(argv):
    """Return the --params-file paths among the ROS arguments of argv, in order."""
    files, in_ros_arguments, arguments = [], False, iter(argv)
    for argument in arguments:
        if argument == '--ros-args':
            in_ros_arguments = True
        elif argument == '--':
            in_ros_arguments = False
        elif in_ros_arguments and argument == '--params-file':
            files.append(next(arguments, None))
    return [path for path in files if path]


def log_parameter_files(node, argv):
    """
    Log the sections of each --params-file of argv that apply to node, as rcl applied them.

    A section that names the node but applies to another namespace (`relief_valve:` for
    /rig1/relief_valve) is a warning: rcl ignores it without a word.
    """
    fqn, logger = node.get_fully_qualified_name(), node.get_logger()
    files = []
    for path in parameter_file_arguments(argv):
        try:
            files.append((path, parameter_document(path)))
        except ParameterError as error:  # rcl read it; it changed or vanished since
            logger.warn(str(error))
    try:
        sections = parameters_for_node(files, fqn)
    except ValueError as error:
        logger.warn(f'parameter file {error}')
        return
    for path, _ in files:
        applied = [name for source, name in sections.applied if source == path]
        logger.info(
            f"parameter file {path}: applied section(s) {', '.join(applied)} to {fqn}"
            if applied
            else f'parameter file {path}: no section applies to {fqn}'
        )
    if sections.not_applied:
        logger.warn(f'{describe_not_applied(sections, fqn)}: their values are not used')
