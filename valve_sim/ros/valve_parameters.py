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

from typing import Callable, NamedTuple

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
    for name in filter(retired_reason, overridden_names(node)):
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


def overridden_names(node):
    """
    Return the names of the parameters that node's parameter files and -p set, declared or not.

    rclpy has no public API for a node's overrides: only Node._parameter_overrides holds
    the undeclared ones (the only reader of that private attribute in valve_sim).
    """
    return list(node._parameter_overrides)


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


class DeclaredParameters:
    """
    A node's declared parameters as ValveParameters reads and sets them: a small mapping.

    declared[name]: the value declared; name in declared: whether it is declared;
    declared.set_values(parameters): set them through rclpy's own Node.set_parameters_atomically,
    past the checks a ReliefValveNode adds (its parameter callbacks still run).
    """

    def __init__(self, node):
        self._node = node

    def __contains__(self, name):
        return self._node.has_parameter(name)

    def __getitem__(self, name):
        return self._node.get_parameter(name).value

    def set_values(self, parameters):
        """Set rclpy Parameters as the node's declared values, past the node's own checks."""
        Node.set_parameters_atomically(self._node, parameters)


class NodeHooks(NamedTuple):
    """What ValveParameters asks of the node it serves."""

    settings: Callable[[], dict]  # the run-time settings in use (SETTING_SPECS)
    use_settings: Callable[[dict], None]  # use new settings (a new publish_rate: a new timer)
    resume: Callable[[str], None]  # let a halted model advance again, for the cause given
    publish_fault_status: Callable[[], None]  # the faults and sensor settings in effect


class ValveParameters:
    """
    The live parameter changes of a ReliefValveNode: checked, planned, applied.

    Given what it needs, no node: declared (DeclaredParameters, or a mapping with set_values()),
    the parts a change acts on (model: RealTimeModel; injection: FaultInjection; inputs:
    (InletFlowInput, TankPressureInput), whose limits follow the parameters;
    schedule_loader: ScheduleLoader; status: NodeStatus, where refusals are counted),
    hooks (NodeHooks) and logger. The node adds complete, check and apply as its pre-set,
    on-set and post-set parameter callbacks.
    """

    def __init__(self, declared, model, injection, inputs, schedule_loader, status, hooks,
                 logger):
        self.declared = declared
        self.model = model
        self.injection = injection
        self.inlet, self.tank = inputs
        self.schedule_loader = schedule_loader
        self.status = status
        self.hooks = hooks
        self.logger = logger
        self.restoring = False  # set_declared at work: the callbacks let the values pass
        self.plan = None  # ChangePlan of the change being set
        self.before = {}  # declared values of the change being set, before it
        self.undo = {}  # declared values before the last change that retuned the model
        self.opened_schedule = None  # the file a change being set sets as fault_schedule

    def set_atomically(self, parameter_list, set_declared_values):
        """
        Node.set_parameters_atomically, which both parameter services call.

        Checks each value against its spec first, for a reason with symbol, limits
        and unit, and each name (an undeclared one is named, with the declared name
        meant), and counts and logs every refusal.
        """
        problems = (
            value_problem(VALVE_SPECS[p.name], p)
            if p.name in VALVE_SPECS
            else None
            if p.name in self.declared
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
        self.status.counters.rejected_parameter_changes += 1
        self.logger.warn(f'parameter change refused: {reason}')

    def complete(self, parameters):
        """Pre-set callback: integers as doubles; plan the change, add what it implies."""
        parameters = integers_as_doubles(parameters, VALVE_SPECS)
        changes = {p.name: p.value for p in parameters if p.name in LIVE_NAMES}
        if self.restoring:  # values in use again: the dependent one only keeps them agreeing
            try:
                dependent = dependent_change(self.model.params, changes)
            except (ParameterError, SteadyStateError):
                dependent = {}
        else:
            self.plan = changes and plan_change(
                self.model, self.hooks.settings(), changes, self.inlet.flow, self.tank.value,
                self.injection.sensors,
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
            name: self.declared[name] for name in self.plan.changes if name != FAULT_SCHEDULE
        }
        return SetParametersResult(successful=True)

    def _open_schedule(self, path):
        """
        Open (not read) a schedule file set live; '' sets none. Raises InputFileError.

        The file is read and checked on the loader's thread (take_schedule applies it).
        """
        loader = self.schedule_loader
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
        parts = plan.parts
        before, self.before = self.before, {}
        if self.model.retune(plan.params, plan.settings['step_size'], parts.fault or None):
            self.undo = before  # what a roll-back of this change restores
        self.injection.sensors.change(parts.sensor)
        if FAULT_SCHEDULE in plan.changes:
            self._load_schedule(plan.changes[FAULT_SCHEDULE])
        if parts.fault or parts.sensor:
            self.hooks.publish_fault_status()
        self._limit_inputs(plan.params, plan.settings)
        if 'tank_pressure' in plan.changes and self.tank.value is not None:
            self.logger.warn(
                'tank_pressure set, but the tank_pressure topic sets the tank pressure '
                f'({self.tank.gauge():g} Pa gauge): the topic takes precedence'
            )
        self.hooks.use_settings(plan.settings)
        self.hooks.resume('a parameter change')
        self.logger.info(f'parameters set: {plan.changes}')

    def _limit_inputs(self, params, settings):
        """Make the inputs' limits follow the parameters and settings in use (rule kept here)."""
        self.inlet.max_inlet_flow = params['max_inlet_flow']
        self.tank.ambient_pressure = settings['ambient_pressure']
        self.tank.burst_pressure = params['burst_pressure']

    def _load_schedule(self, path):
        """Read the schedule file opened by the check on the loader's thread ('': none, now)."""
        stream, self.opened_schedule = self.opened_schedule, None
        if not path:
            self.injection.use_events((), '')
            return
        self.schedule_loader.start(path, stream)
        self.logger.info(f'reading fault schedule {path}: in use once it is checked')

    def take_schedule(self):
        """
        At a tick: use a schedule the loader has read and checked, from this tick on.

        A file the loader refused is logged, counted as a refused parameter change, shown
        in the diagnostics (fault_schedule_refused), and fault_schedule is set back to
        the file in use.
        """
        loaded = self.schedule_loader.take()
        if loaded is None:
            return
        path, events = loaded
        if not isinstance(events, str):
            self.injection.use_events(events, path)
            self.logger.info(
                f'fault schedule {path} in use: {len(events)} events, t from this tick'
            )
            return
        self.status.schedule_refused = f'{path}: {events}'
        self.status.counters.refused_fault_schedules += 1
        self.count_refusal(f'fault_schedule {path}: {events}')
        self.set_declared({FAULT_SCHEDULE: self.injection.schedule_path})

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
        model, parts = self.model, split(changes)
        message = f'fault schedule at t = {model.time_ns / NS_PER_S:.6f} s: {changes}'
        try:
            self.injection.sensors.checked(parts.sensor)
        except ParameterError as error:
            self.count_refusal(str(error))
            self.logger.error(f'{message} refused: {error}')
            return
        before = {name: self.declared[name] for name in changes}
        self.set_declared(changes)
        if model.retune(model.params, model.step_size, parts.fault or None):
            self.undo = before  # what a roll-back of this event restores
        self.injection.sensors.change(parts.sensor)
        self.hooks.publish_fault_status()
        self.hooks.resume('a scheduled fault')
        self.logger.info(message)

    def set_declared(self, values):
        """Set declared parameter values {name: value} that differ, without the callbacks."""
        changed = [
            Parameter(name, value=value)
            for name, value in values.items()
            if self.declared[name] != value
        ]
        if not changed:
            return
        self.restoring = True
        try:
            self.declared.set_values(changed)
        finally:
            self.restoring = False

    def restore(self):
        """
        After the model rolled back its last change: the rest of that change undone too.

        Settings and sensor settings of the change return to their values before it,
        and the node's declared parameters to what is in use (the model's parameters,
        step size and faults, and every other value of the change): all agree again,
        and a later change cannot bring back a part of the one undone. The inputs'
        limits follow.
        """
        model = self.model
        undo, self.undo = self.undo, {}
        self.injection.sensors.change(split(undo).sensor)
        settings = {**self.hooks.settings(), **split(undo).setting}
        self.hooks.use_settings(settings)
        self.set_declared(
            {
                **undo,
                **model.params,
                'step_size': model.step_size,
                **model.faults.as_parameters(),
            }
        )
        self._limit_inputs(model.params, settings)
        self.hooks.publish_fault_status()
