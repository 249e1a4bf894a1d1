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
valve_node's parameters: declared, and every live change planned once, applied once.

In the manner of ros2/demos demo_nodes_py, three callbacks, each with one job:
  pre-set   plan the change (core.retuning.plan_change: the cracking point solved
            once) and add the parameter it implies (preset_pressure or the preload);
  on-set    refuse it with the plan's problem, else open a new fault schedule file;
  post-set  apply the plan from the next tick on, without solving again.
Values set by the node itself (a roll-back, a scheduled fault: apply_scheduled, a
refused schedule file) go through set_declared, which the on-set and post-set
callbacks let pass.
"""

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.node import Node
from rclpy.parameter import Parameter
from valve_sim.core.catalogue import LIVE_NAMES, split, VALVE_NODE_SPECS
from valve_sim.core.errors import InputFileError, ParameterError, SteadyStateError
from valve_sim.core.parameters import (
    FAULT_SCHEDULE,
    load_parameters,
    PARAMETERS,
    PRESET_PRESSURE,
    retired_reason,
    SETTING_SPECS,
    SETTINGS,
    SPECS,
    validate,
)
from valve_sim.core.realtime_model import NS_PER_S
from valve_sim.core.retuning import dependent_change, plan_change
from valve_sim.core.steady_state import cracking_pressure, preload_for_cracking_pressure
from valve_sim.ros.ros_parameters import (
    declare_double,
    integers_as_doubles,
    undeclared_reason,
    value_problem,
)

# All double parameters (the catalogue's doubles of valve_node).
VALVE_SPECS = {name: spec for name, spec in VALVE_NODE_SPECS.items() if spec.kind == 'double'}


def declare_valve_parameters(node):
    """
    Declare the model parameters and settings, defaults from config/reference.yaml.

    Then preset_pressure, by default the cracking pressure; an override sets the
    preload. Returns (params, settings).
    """
    reference = load_parameters()
    defaults = {**reference.params, **reference.settings}
    # rclpy drops an undeclared override silently: say so for a retired parameter that
    # a parameter file (an older calibrated.yaml) still sets.
    for name in filter(retired_reason, node._parameter_overrides):
        node.get_logger().warning(f'ignoring {name} (a parameter file or -p sets it): '
                                  f'{retired_reason(name)}')
    values = {
        spec.name: declare_double(node, spec, defaults[spec.name], not spec.live)
        for spec in PARAMETERS + SETTINGS
    }
    params = validate({name: values[name] for name in SPECS})
    settings = {name: values[name] for name in SETTING_SPECS}
    cracking = cracking_pressure(params)
    preset = declare_double(node, PRESET_PRESSURE, cracking)
    if preset == cracking:
        return params, settings
    preload = preload_for_cracking_pressure(params, preset)
    node.set_parameters([Parameter('pilot_spring_preload', value=preload)])
    return {**params, 'pilot_spring_preload': preload}, settings


def declare_choice(node, name, choices, description):
    """Declare a read-only string parameter, the first of choices by default; return it."""
    descriptor = ParameterDescriptor(name=name, description=description, read_only=True)
    choice = node.declare_parameter(name, next(iter(choices)), descriptor).value
    if choice not in choices:
        raise ParameterError(f"{name} must be one of {', '.join(choices)}, got {choice!r}")
    return choice


def declare_frame_prefix(node):
    """Declare frame_prefix (read-only): the pressures' frames are it + their place."""
    descriptor = ParameterDescriptor(
        name='frame_prefix',
        description=(
            "prefix of the pressure messages' header.frame_id (+ supply_port, "
            'intermediate_chamber, pilot_chamber, poppet_chamber); default: node name + /'
        ),
        read_only=True,
    )
    return node.declare_parameter('frame_prefix', node.get_name() + '/', descriptor).value


class ValveParameters:
    """The live parameter changes of a ReliefValveNode: checked, planned, applied."""

    def __init__(self, node):
        self.node = node
        self.restoring = False  # set_declared at work: the callbacks let the values pass
        self.plan = None  # ChangePlan of the change being set
        self.before = {}  # declared values of the change being set, before it
        self.undo = {}  # declared values before the last change that retuned the model
        self.opened_schedule = None  # the file a change being set sets as fault_schedule
        node.add_pre_set_parameters_callback(self.complete)
        node.add_on_set_parameters_callback(self.check)
        node.add_post_set_parameters_callback(self.apply)

    def set_atomically(self, parameter_list, set_declared_values):
        """
        Node.set_parameters_atomically, which both parameter services call.

        Checks each value against its spec first, for a reason with symbol, limits
        and unit, and each name (an undeclared one is named, with the declared name
        meant), and counts and logs every refusal.
        """
        node = self.node
        problems = (
            value_problem(VALVE_SPECS[p.name], p)
            if p.name in VALVE_SPECS
            else None
            if node.has_parameter(p.name)
            else retired_reason(p.name) or undeclared_reason(p.name, VALVE_SPECS)
            for p in parameter_list
        )
        reason = next(filter(None, problems), None)
        try:
            result = (
                SetParametersResult(successful=False, reason=reason)
                if reason
                else set_declared_values(parameter_list)
            )
        except ParameterNotDeclaredException as error:
            self.count_refusal(str(error))
            raise
        if not result.successful:
            self.count_refusal(result.reason)
        return result

    def count_refusal(self, reason):
        """Count and log a refused parameter change."""
        self.node.status.counters.rejected_parameter_changes += 1
        self.node.get_logger().warn(f'parameter change refused: {reason}')

    def complete(self, parameters):
        """Pre-set callback: integers as doubles; plan the change, add what it implies."""
        parameters = integers_as_doubles(parameters, VALVE_SPECS)
        changes = {p.name: p.value for p in parameters if p.name in LIVE_NAMES}
        if self.restoring:  # values in use again: the dependent one only keeps them agreeing
            try:
                dependent = dependent_change(self.node.model.params, changes)
            except (ParameterError, SteadyStateError):
                dependent = {}
        else:
            node = self.node
            self.plan = changes and plan_change(
                node.model, node.settings, changes, node.inlet_flow, node.tank_input.value,
                node.injection.sensors,
            )
            dependent = self.plan.dependent if self.plan else {}
        return parameters + [
            Parameter(name, Parameter.Type.DOUBLE, value) for name, value in dependent.items()
        ]

    def check(self, parameters):
        """On-set callback: refuse a change with the plan's problem; open a new schedule."""
        if not self.plan or self.restoring:
            return SetParametersResult(successful=True)
        try:
            if self.plan.problem:
                raise ParameterError(self.plan.problem)
            if FAULT_SCHEDULE in self.plan.changes:
                self._open_schedule(self.plan.changes[FAULT_SCHEDULE])
        except (ParameterError, InputFileError) as error:
            return SetParametersResult(successful=False, reason=str(error))
        self.before = {
            name: self.node.get_parameter(name).value
            for name in self.plan.changes
            if name != FAULT_SCHEDULE
        }
        return SetParametersResult(successful=True)

    def _open_schedule(self, path):
        """
        Open (not read) a schedule file set live; '' sets none. Raises InputFileError.

        The file is read and checked on the loader's thread (take_schedule applies it).
        """
        loader = self.node.schedule_loader
        if loader.loading:
            raise ParameterError(
                f'fault schedule {loader.loading} is still being read and '
                'checked; set fault_schedule again once the log says it is in use'
            )
        self.opened_schedule = loader.opened(path) if path else None

    def apply(self, parameters):
        """Post-set callback: the planned change takes effect from the next tick."""
        plan, self.plan = self.plan, None
        if not plan or self.restoring:
            return
        node, parts = self.node, plan.parts
        before, self.before = self.before, {}
        if node.model.retune(plan.params, plan.settings['step_size'], parts.fault or None):
            self.undo = before  # what a roll-back of this change restores
        node.injection.sensors.change(parts.sensor)
        if FAULT_SCHEDULE in plan.changes:
            self._load_schedule(plan.changes[FAULT_SCHEDULE])
        if parts.fault or parts.sensor:
            node.publish_fault_status()
        node.input.max_inlet_flow = plan.params['max_inlet_flow']
        node.tank_input.ambient_pressure = plan.settings['ambient_pressure']
        node.tank_input.burst_pressure = plan.params['burst_pressure']
        if 'tank_pressure' in plan.changes and node.tank_input.value is not None:
            node.get_logger().warn(
                'tank_pressure set, but the tank_pressure topic sets the tank pressure '
                f'({node.tank_input.gauge():g} Pa gauge): the topic takes precedence'
            )
        node.use_settings(plan.settings)
        node.resume('a parameter change')
        node.get_logger().info(f'parameters set: {plan.changes}')

    def _load_schedule(self, path):
        """Read the schedule file opened by the check on the loader's thread ('': none, now)."""
        stream, self.opened_schedule = self.opened_schedule, None
        if not path:
            self.node.injection.use_events((), '')
            return
        self.node.schedule_loader.start(path, stream)
        self.node.get_logger().info(f'reading fault schedule {path}: in use once it is checked')

    def take_schedule(self):
        """
        At a tick: use a schedule the loader has read and checked, from this tick on.

        A file the loader refused is logged, counted as a refused parameter change, shown
        in the diagnostics (fault_schedule_refused), and fault_schedule is set back to
        the file in use.
        """
        node = self.node
        loaded = node.schedule_loader.take()
        if loaded is None:
            return
        path, events = loaded
        if not isinstance(events, str):
            node.injection.use_events(events, path)
            node.get_logger().info(
                f'fault schedule {path} in use: {len(events)} events, t from this tick'
            )
            return
        node.status.schedule_refused = f'{path}: {events}'
        node.status.counters.refused_fault_schedules += 1
        self.count_refusal(f'fault_schedule {path}: {events}')
        self.set_declared({FAULT_SCHEDULE: node.injection.schedule_path})

    def apply_scheduled(self, changes):
        """
        Apply a schedule event's fault and sensor changes directly, from this tick on.

        Not through the parameter service: the events were checked when the file was
        read, and a fault leaves the model parameters (so the cracking point) as they
        are. Only the sensor settings together are checked here (range_min below
        range_max). The declared values are set, so parameter values and
        /parameter_events show the event; a failure it causes within the trial window
        rolls it back as it does a parameter change (restore).
        """
        node, parts = self.node, split(changes)
        message = f'fault schedule at t = {node.model.time_ns / NS_PER_S:.6f} s: {changes}'
        try:
            node.injection.sensors.checked(parts.sensor)
        except ParameterError as error:
            self.count_refusal(str(error))
            node.get_logger().error(f'{message} refused: {error}')
            return
        before = {name: node.get_parameter(name).value for name in changes}
        self.set_declared(changes)
        if node.model.retune(node.model.params, node.model.step_size, parts.fault or None):
            self.undo = before  # what a roll-back of this event restores
        node.injection.sensors.change(parts.sensor)
        node.publish_fault_status()
        node.resume('a scheduled fault')
        node.get_logger().info(message)

    def set_declared(self, values):
        """Set declared parameter values {name: value} that differ, without the callbacks."""
        changed = [
            Parameter(name, value=value)
            for name, value in values.items()
            if self.node.get_parameter(name).value != value
        ]
        if not changed:
            return
        self.restoring = True
        try:
            Node.set_parameters_atomically(self.node, changed)
        finally:
            self.restoring = False

    def restore(self):
        """
        After the model rolled back its last change: the rest of that change undone too.

        Settings and sensor settings of the change return to their values before it,
        and the node's declared parameters to what is in use (the model's parameters,
        step size and faults, and every other value of the change): all agree again,
        and a later change cannot bring back a part of the one undone.
        """
        node = self.node
        undo, self.undo = self.undo, {}
        node.injection.sensors.change(split(undo).sensor)
        node.use_settings({**node.settings, **split(undo).setting})
        self.set_declared(
            {
                **undo,
                **node.model.params,
                'step_size': node.model.step_size,
                **node.model.faults.as_parameters(),
            }
        )
        node.publish_fault_status()
