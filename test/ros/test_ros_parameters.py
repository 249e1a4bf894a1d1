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

"""Spec -> ParameterDescriptor, lenient double declaration, value checks, preset_pressure logic."""

import math

import pytest
import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.parameter import Parameter
from valve_sim.core.parameters import SPECS
from valve_sim.core.retuning import dependent_change
from valve_sim.core.steady_state import cracking_pressure
from valve_sim.ros.ros_parameters import (
    declare_double,
    descriptor,
    integers_as_doubles,
    value_problem,
)


MASS = SPECS['main_valve_mass']


def node_with(context, **overrides):
    """Create an rclpy node in this process with overrides, as a parameter file would give."""
    overrides = [Parameter(name, value=value) for name, value in overrides.items()]
    return rclpy.create_node('declaring', context=context, parameter_overrides=overrides)


def test_descriptor_carries_symbol_unit_source_and_range():
    described = descriptor(MASS, read_only=True)
    assert '(m_m) [kg]' in described.description and 'Table 1' in described.description
    assert described.floating_point_range[0].from_value == MASS.minimum
    assert described.floating_point_range[0].to_value == MASS.maximum
    assert described.read_only


def test_an_integer_override_is_declared_as_a_double(context):
    node = node_with(context, main_valve_mass=1, main_valve_damping=0.5)
    assert declare_double(node, MASS, 0.065) == 1.0
    assert node.get_parameter('main_valve_mass').type_ == Parameter.Type.DOUBLE
    assert declare_double(node, SPECS['main_valve_damping'], 0.0) == 0.5
    assert declare_double(node, SPECS['pilot_poppet_mass'], 0.008) == 0.008
    node.destroy_node()


def test_a_bad_override_is_refused_at_declaration(context):
    node = node_with(context, main_valve_mass='heavy', pilot_poppet_mass=-1.0)
    with pytest.raises(InvalidParameterTypeException):
        declare_double(node, MASS, 0.065)
    with pytest.raises(InvalidParameterValueException):
        declare_double(node, SPECS['pilot_poppet_mass'], 0.008)
    node.destroy_node()


def test_integers_become_doubles_only_for_double_parameters():
    converted = integers_as_doubles(
        [Parameter('main_valve_mass', value=1), Parameter('other', value=1)], {'main_valve_mass'}
    )
    assert [(p.type_, p.value) for p in converted] == [
        (Parameter.Type.DOUBLE, 1.0),
        (Parameter.Type.INTEGER, 1),
    ]


@pytest.mark.parametrize(
    'value, words',
    [
        ('heavy', ('main_valve_mass', 'must be a number in kg', 'string')),
        (math.nan, ('main_valve_mass', 'finite')),
        (-1.0, ('main_valve_mass', 'limits [0.0001, 10] kg')),
    ],
)
def test_value_problem_names_parameter_limit_and_unit(value, words):
    problem = value_problem(MASS, Parameter('main_valve_mass', value=value))
    assert all(word in problem for word in words), problem
    assert value_problem(MASS, Parameter('main_valve_mass', value=1)) is None


def test_preset_pressure_sets_the_preload_and_model_changes_report_the_new_cracking_pressure(
    reference,
):
    preset = cracking_pressure(reference) + 2e5
    preload = dependent_change(reference, {'preset_pressure': preset})['pilot_spring_preload']
    moved = {**reference, 'pilot_spring_preload': preload}
    assert cracking_pressure(moved) == pytest.approx(preset, rel=1e-9)
    stiffer = dependent_change(
        reference, {'pilot_spring_stiffness': reference['pilot_spring_stiffness'] * 1.1}
    )
    assert stiffer['preset_pressure'] > cracking_pressure(reference)
    assert dependent_change(reference, {'step_size': 2e-5}) == {}
