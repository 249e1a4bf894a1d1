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
valve_node: the virtual relief valve as a real-time ROS 2 node (docs/valve_node.md).

Names are relative, so namespaces and remapping work. Pressures are ABSOLUTE [Pa] on the wire.
  sub inlet_flow             std_msgs/Float64           q_in [m^3/s], taken by the tick itself
  sub tank_pressure          sensor_msgs/FluidPressure  overrides the tank_pressure parameter
  pub supply_pressure, intermediate_pressure, pilot_pressure, poppet_chamber_pressure
                             sensor_msgs/FluidPressure  the sensor stage's readings
  pub joint_states           sensor_msgs/JointState     main_valve, pilot_poppet: [m], [m/s]
  pub applied_inlet_flow     sensor_msgs/JointState     q_in applied over the tick to the stamp
  pub applied_tank_pressure  sensor_msgs/FluidPressure  the tank pressure applied over it
  pub relief_flow            sensor_msgs/JointState     to the tank [m^3/s], and its three parts
  pub /diagnostics           diagnostic_msgs/DiagnosticArray  1 Hz (valve_diagnostics)
  pub fault_status           diagnostic_msgs/DiagnosticArray  latched faults and sensor settings
  srv ~/reset                std_srvs/Trigger           the exact steady state of the inlet flow
  srv ~/restart              rcl_interfaces/SetParametersAtomically  the start-up state, in
                             place: parameters (and these over them), a new time base

All messages of one tick carry the model time of the state as header.stamp. The model
(valve_sim.core.realtime_model, no ROS) decides what a tick comes to; this module adapts
it: inputs, the tick timer, the outcome's counters, the reset service. Parameters
(ros.valve_parameters: declarations, a change planned once and applied once),
housekeeping (ros.housekeeping), the outcome's logs (ros.tick_logs), all three given what
they need, and the /diagnostics report (ros.valve_diagnostics) live apart. Faults and sensors
(docs/faults.md): parameters fault.* and sensor.*, and a schedule file whose events are
applied at the tick, directly. The process (command line, main) is ros.valve_node_main;
with its --foxglove [PORT] the tick topics and /diagnostics are also served over
Foxglove's WebSocket protocol.
"""

import time

from rclpy.node import Node
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from valve_sim.core.errors import ParameterError, SteadyStateError
from valve_sim.core.model import P_S
from valve_sim.core.parameters import NODE_NAME
from valve_sim.core.realtime_model import NS_PER_S, RealTimeModel, Status
from valve_sim.ros import diagnostics, valve_restart
from valve_sim.ros.clock_guard import GuardedTimeSource
from valve_sim.ros.clock_jumps import tick_times
from valve_sim.ros.fault_injection import (
    declare_fault_parameters,
    FaultInjection,
    ScheduleLoader,
)
from valve_sim.ros.housekeeping import Housekeeping, WatchedInput
from valve_sim.ros.lockstep_inputs import declare_lockstep_inputs, LockstepInputs
from valve_sim.ros.node_status import NodeStatus
from valve_sim.ros.receive_threads import DEFAULT_POLICY, ReceiveThreads
from valve_sim.ros.ros_parameters import log_parameter_files
from valve_sim.ros.tick_logs import TickLogs
from valve_sim.ros.valve_diagnostics import ValveDiagnostics
from valve_sim.ros.valve_inputs import (
    INLET_FLOW_QOS,
    InletFlowInput,
    INPUT_SHARE,
    INPUTS_PER_TICK,
    RELIABILITY_DESCRIPTION,
    TankPressureInput,
)
from valve_sim.ros.valve_outputs import ValveOutputs
from valve_sim.ros.valve_parameters import (
    declare_choice,
    declare_frame_prefix,
    declare_valve_parameters,
    DeclaredParameters,
    NodeHooks,
    ValveParameters,
)


READY_MESSAGE = 'ready'  # start of the log line that says the node ticks from now on
CATCH_UP_LIMIT_PERIODS = 50  # a tick integrates at most this many tick periods of lag


class ReliefValveNode(Node):
    """The valve model on a timer at publish_rate, fed by inlet_flow, publishing its state."""

    def __init__(self, argv=(), **kwargs):
        self.inlet_subscription = None  # taken by the tick, left out of subscriptions
        self.tank_subscription = None  # likewise
        self.stamped_subscriptions = ()  # likewise: the lockstep inputs' (lockstep_inputs)
        super().__init__(NODE_NAME, **kwargs)
        self.set_up(argv)

    def set_up(self, argv=()):
        """Everything but the bare node (a managed node runs it when configured)."""
        self.clock_guard = GuardedTimeSource.install(self)
        log_parameter_files(self, argv)  # which sections of its --params-file apply
        started = time.perf_counter()  # the preset's cracking point is the first kernel call
        params, self.settings = declare_valve_parameters(self)
        self.hardware_id = diagnostics.declare_hardware_id(self)
        self.frame_prefix = declare_frame_prefix(self)
        faults, sensors, schedule = declare_fault_parameters(self)
        self.injection = FaultInjection(sensors, schedule)
        self.tank_input = TankPressureInput(
            self.settings['ambient_pressure'], params['burst_pressure']
        )
        problem = self.tank_input.problem(self.settings['tank_pressure'] + self.ambient_pressure)
        if problem:
            raise ParameterError(f"parameter 'tank_pressure' (p_t): {problem}")
        self.model = RealTimeModel(
            params, self.settings['step_size'], self.settings['initial_inlet_flow'], faults,
            self.tank_pressure, self.ambient_pressure,
        )
        # Compile (or load from numba's cache) the integration kernel before the tick timer
        # exists: compiled in the first tick, it would stall the clock for seconds.
        self.model.trial(params, self.settings['step_size'], self.settings['initial_inlet_flow'])
        self.kernels_seconds = time.perf_counter() - started  # also in /diagnostics
        self.input = InletFlowInput(self.settings['initial_inlet_flow'], params['max_inlet_flow'])
        self.applied_flow = self.inlet_flow  # [m^3/s], over the last tick
        self.status = NodeStatus(time.monotonic_ns())
        self.logs = TickLogs(self.get_logger(), self.status.counters, CATCH_UP_LIMIT_PERIODS)
        self.schedule_loader = ScheduleLoader()
        self.outputs = ValveOutputs(self, self.frame_prefix)
        self.diagnostics = ValveDiagnostics(self)
        self.publish_fault_status()
        input_qos = INLET_FLOW_QOS[
            declare_choice(self, 'inlet_flow_reliability', INLET_FLOW_QOS, RELIABILITY_DESCRIPTION)
        ]
        self.inlet_subscription = self.create_subscription(
            Float64, 'inlet_flow', self.input.offer_cdr, input_qos, raw=True
        )
        self.lockstep_inputs = LockstepInputs(
            self, declare_lockstep_inputs(self), self.input, self.tank_input
        )
        self.tank_subscription = self.create_subscription(
            FluidPressure, 'tank_pressure', self.tank_input.offer_cdr,
            self.lockstep_inputs.tank_qos(input_qos), raw=True
        )
        self.lockstep_inputs.add_tank_subscription(self.tank_subscription)
        self.stamped_subscriptions = self.lockstep_inputs.subscriptions
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.receive_threads = ReceiveThreads(DEFAULT_POLICY)  # main() sets its --receive-threads
        self.housekeeping = Housekeeping(
            self.status.counters,
            (WatchedInput('inlet_flow', self.input, self.inlet_subscription,
                          lambda: f'{self.inlet_flow:g} m^3/s'),
             WatchedInput('tank_pressure', self.tank_input, self.tank_subscription,
                          lambda: f'{self.tank_pressure:g} Pa (gauge)')),
            self.clock_guard, self.take_inputs,
            chores=(self._update_receive_threads, self.diagnostics.publish),
            logger=self.get_logger(), create_timer=self.create_timer,
            period=diagnostics.declare_period(self),
        )
        self._tick_timer = self._create_tick_timer()
        self.parameters = ValveParameters(
            DeclaredParameters(self), self.model, self.injection, (self.input, self.tank_input),
            self.schedule_loader, self.status, logger=self.get_logger(), hooks=NodeHooks(
                lambda: self.settings, self.use_settings, self.resume, self.publish_fault_status),
        )
        self.add_pre_set_parameters_callback(self.parameters.complete)
        self.add_on_set_parameters_callback(self.parameters.check)
        self.add_post_set_parameters_callback(self.parameters.apply)
        self.start_values = valve_restart.StartValues(self)  # what ~/restart goes back to
        valve_restart.serve(self)
        self.get_logger().info(
            f'valve at the steady state of {self.inlet_flow:g} m^3/s'
            + (f' into a tank at {self.tank_pressure:g} Pa (gauge)' if self.tank_pressure else '')
            + f': p_s = {self.model.state[P_S]:.6g} Pa (gauge); '
            f'{self.settings["publish_rate"]:g} Hz, steps of {self.settings["step_size"]:g} s'
        )
        self.get_logger().info(
            f'{READY_MESSAGE}: model kernels compiled or loaded in {self.kernels_seconds:.2f} s; '
            'ticking from the first timer call'
        )

    @property
    def inlet_flow(self):
        """Return the last good inlet flow [m^3/s]: what the next tick applies."""
        return self.input.flow

    @property
    def ambient_pressure(self):
        """Return the ambient pressure [Pa absolute]: the zero of the gauge pressures."""
        return self.settings['ambient_pressure']

    @property
    def tank_pressure(self):
        """
        Return the tank pressure [Pa, gauge] the next tick applies.

        The tank_pressure topic's last good value once one came, else the parameter.
        """
        gauge = self.tank_input.gauge()
        return self.settings['tank_pressure'] if gauge is None else gauge

    @property
    def live_view(self):
        """Return the Foxglove LiveView the node serves, or None."""
        return self.outputs.live_view

    @property
    def subscriptions(self):
        """
        Return the subscriptions an executor runs: all but the inputs', the tick takes them.

        Both executors ask the node for these (the EventsExecutor ignores callback
        groups), so a flood of inlet_flow or tank_pressure never wakes the executor and
        never queues callbacks ahead of the tick (take_inputs).
        """
        taken = (self.inlet_subscription, self.tank_subscription, *self.stamped_subscriptions)
        return (s for s in super().subscriptions if s not in taken)

    # --- parameters (ros.valve_parameters) -------------------------------------------------

    def set_parameters_atomically(self, parameter_list):
        """Node.set_parameters_atomically, which both parameter services call, checked first."""
        return self.parameters.set_atomically(parameter_list, super().set_parameters_atomically)

    def use_settings(self, settings):
        """Use the run-time settings; a new publish_rate recreates the tick timer."""
        rate_changed = settings['publish_rate'] != self.settings['publish_rate']
        self.settings = settings
        self.model.use_ambient(settings['ambient_pressure'])  # the vapour pressure's gauge zero
        if rate_changed:
            self.destroy_timer(self._tick_timer)
            self._tick_timer = self._create_tick_timer()

    # --- stepping ---------------------------------------------------------------------------

    def _create_tick_timer(self):
        self.status.previous_slot_ns = None
        return self.create_timer(1.0 / self.settings['publish_rate'], self._tick)

    def _tick(self):
        """
        Advance the model to the clock and publish its state: once per period of a jump.

        A /clock jump of a few whole tick periods (clock_jumps) is ticked period by
        period, each tick with its own stamp, as if /clock had come once per period;
        the inputs are taken once, before the first of them.
        """
        started = time.perf_counter_ns()
        now_ns = self.get_clock().now().nanoseconds
        self.take_inputs(started)
        *earlier, _ = tick_times(self.model.time_ns, now_ns, self._tick_timer.timer_period_ns,
                                 self.get_clock().ros_time_is_active)
        for time_ns in earlier:  # each in its own timer slot: neither late nor missing any
            self._tick_at(time_ns, started, time_ns)
            started = time.perf_counter_ns()
        self._tick_at(now_ns, started)
        self.housekeeping.after_tick()

    def _tick_at(self, now_ns, started, slot_ns=None):
        """One tick at the clock time now_ns [ns] (started: its perf_counter_ns start)."""
        starting = self.model.time_ns is None or now_ns < self.model.time_ns
        if starting:
            self._start(now_ns)
        self.input.stamp(now_ns)
        self.tank_input.stamp(now_ns)
        if not starting:
            self._count_lateness(now_ns, slot_ns)
            self.lockstep_inputs.settle(  # stamped inputs: on /clock, wait for t_k's
                self.model.time_ns, self.get_clock().ros_time_is_active)
            self._advance(now_ns)
        self._inject()
        self.outputs.publish_tick(
            self.model, self.applied_flow, self.ambient_pressure, self.injection
        )
        self.status.tick_done(time.perf_counter_ns() - started, self._tick_timer.timer_period_ns)

    def _start(self, now_ns):
        """
        Anchor the model time to the clock: at the first tick, or when the clock jumped back.

        A jump back starts a new time base: everything timed (the roll-back window, the
        schedule's origin, the sensors' lag, the input's age) moves with the model time.
        """
        if self.model.time_ns is not None:
            shift_ns = now_ns - self.model.time_ns
            self.status.counters.clock_jumps_back += 1
            self.get_logger().warn(
                f'clock jumped back by {-shift_ns / NS_PER_S:g} s; model time restarts from '
                'the clock, in a new time base'
            )
            self.injection.rebase(shift_ns)
            self.input.rebase(shift_ns)
            self.tank_input.rebase(shift_ns)
        self.model.start(now_ns)
        self.input.received_ns = self.input.received_ns or now_ns
        self.tank_input.received_ns = self.tank_input.received_ns or now_ns
        self.status.previous_slot_ns = None

    def _count_lateness(self, now_ns, slot_ns=None):
        """
        Count this tick as late or not, and the timer slots that passed without a tick.

        slot_ns: the tick's own slot [ns] in a clock jump; None: the timer's newest slot.
        """
        period_ns = self._tick_timer.timer_period_ns
        if slot_ns is None:
            slot_ns = now_ns + self._tick_timer.time_until_next_call() - period_ns
        self.status.tick_started(now_ns, slot_ns, period_ns)

    def _advance(self, now_ns):
        """Advance the model to now_ns; count, log and follow through the Outcome it returns."""
        period_ns = self._tick_timer.timer_period_ns
        if self.input.changed:
            self.input.changed = False
            self.resume('a new inlet flow')
        if self.tank_input.changed:
            self.tank_input.changed = False
            self.resume('a new tank pressure')
        outcome = self.model.update(
            now_ns, self.inlet_flow, CATCH_UP_LIMIT_PERIODS * period_ns, self.tank_pressure
        )
        self.status.count(outcome, period_ns)
        if outcome.status is Status.PROGRESS:
            self.applied_flow = self.inlet_flow
            if outcome.skipped_ns:
                self.logs.lag_skipped(outcome.skipped_ns)
        elif outcome.error is not None:  # the last good state held; a roll-back followed through
            self.logs.failure(outcome, self.model.saturated, self.model.saturated_chamber)
            if outcome.rolled_back:  # the rest of the undone change too (settings, limits)
                self.parameters.restore()

    def _inject(self):
        """Apply the schedule's events due at this tick; watch for overpressure."""
        self.parameters.take_schedule()
        changes = self.injection.due(self.model.time_ns)
        if changes:
            self.parameters.apply_scheduled(changes)
        limit = self.model.params['supply_pressure_limit']
        overpressure = self.injection.at_supply_limit(self.model.state, limit)
        self.logs.supply_limit(overpressure, self.injection.overpressure, limit, self.model.faults)
        self.injection.overpressure = overpressure

    def resume(self, cause):
        """Let a halted model advance again."""
        if self.model.resume():
            self.logs.resumed(cause)

    # --- inputs and outputs -----------------------------------------------------------------

    def publish_fault_status(self):
        """Publish the faults and sensor settings in effect, stamped from when they hold."""
        self.outputs.publish_fault_status(self.model, self.injection, self.hardware_id)

    def serve_live_view(self, port, host):
        """Serve the tick topics and /diagnostics over Foxglove's WebSocket protocol."""
        self.outputs.serve_live_view(port, host, self.diagnostics.publisher.topic_name)

    def take_inputs(self, started_ns=None):
        """
        Take queued input messages: INPUTS_PER_TICK each.

        In a tick (started_ns: its perf_counter_ns start) none after INPUT_SHARE of its
        period, so that a flood cannot delay the tick; outside a tick (the housekeeping of a
        paused clock, a reset) no deadline: on a loaded machine the share could pass before
        the first take, and a paused clock would then never take the flow sent to it.
        """
        deadline_ns = None if started_ns is None else (
            started_ns + INPUT_SHARE * self._tick_timer.timer_period_ns
        )
        self.input.take(self.inlet_subscription, INPUTS_PER_TICK, deadline_ns)
        self.tank_input.take(self.tank_subscription, INPUTS_PER_TICK, deadline_ns)

    def _on_reset(self, request, response):
        """~/reset: re-initialise at the exact steady state of the current inlet flow."""
        self.take_inputs()  # a flow sent just before the reset counts
        try:
            self.model.reset(self.inlet_flow, self.tank_pressure)
        except SteadyStateError as error:
            response.success = False
            response.message = f'reset refused, the state is kept: {error}'
            self.get_logger().warn(response.message)
            return response
        time_ns = self.model.time_ns or 0
        response.success = True
        response.message = (
            f're-initialised at model time {time_ns // NS_PER_S}.{time_ns % NS_PER_S:09d} s '
            f'at the steady state of {self.inlet_flow:g} m^3/s'
            + (f' and tank pressure {self.tank_pressure:g} Pa' if self.tank_pressure else '')
            + f': p_s = {self.model.state[P_S]:.6g} Pa (gauge)'
        )
        self.get_logger().info(response.message)
        return response

    def use_receive_thread_policy(self, policy):
        """Put the middleware's receive threads under policy (a POLICIES key), now and later."""
        self.receive_threads = ReceiveThreads(policy)
        self._update_receive_threads(say=True)

    def _update_receive_threads(self, say=False):
        """Put receive threads started since the last look under the policy; log any (or say)."""
        threads = self.receive_threads
        if threads.update() or say:
            self.get_logger().info(f'middleware receive threads: {threads.describe()}')
