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
managed_valve_node: valve_node as a managed (lifecycle) node (docs/valve_node.md).

The same node (ros.valve_node: topics, parameters, services, diagnostics), brought up
and down through the standard lifecycle services ~/change_state, ~/get_state,
~/get_available_transitions, with ~/transition_event on every change of state:
  configure   declare and check the parameters, read the files, load or compile the
              kernels, solve the initial steady state; nothing is published
  activate    re-solve the steady state at the present inputs, tick and publish
  deactivate  stop ticking; the state is held, nothing is published
  cleanup     back to unconfigured: the valve's parameters, topics and services go
  shutdown    from any primary state
While active, an overpressure (p_s at supply_pressure_limit) or a halt of the model
deactivates the node itself; the reason goes on /diagnostics before its publishers
fall silent. An error inside a transition (a parameter or file refused at configure, a
steady state that cannot be solved at activate) is logged, and the node goes through
ErrorProcessing, which undoes the configuration, to Unconfigured.
"""

import argparse
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import rclpy
from rclpy.lifecycle import LifecycleNodeMixin, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.utilities import remove_ros_args
from valve_sim.core.model import P_S
from valve_sim.core.parameters import NODE_NAME
from valve_sim.ros import diagnostics, spinning
from valve_sim.ros.receive_threads import DEFAULT_POLICY, POLICIES
from valve_sim.ros.valve_node import ReliefValveNode


LIFECYCLE_TASK = 'lifecycle'  # the /diagnostics status of the node's own deactivations


def logged(transition):
    """Wrap an on_<transition> callback: an exception is logged and becomes ERROR."""
    def wrap(callback):
        def run(self, state):
            try:
                return callback(self, state)
            # rclpy turns any exception of a callback into ERROR without a word: say why
            except Exception as error:  # noqa: B902
                self.get_logger().error(f'{transition} failed: {error}')
                return TransitionCallbackReturn.ERROR
        run.__doc__ = callback.__doc__
        return run
    return wrap


class ManagedReliefValveNode(LifecycleNodeMixin, ReliefValveNode):
    """ReliefValveNode whose set-up, ticking and tear-down follow the lifecycle transitions."""

    def __init__(self, argv=(), **kwargs):
        self.inlet_subscription = self.tank_subscription = None
        self.stamped_subscriptions = ()  # valve_node's lockstep inputs' (set_up makes them)
        self._argv = argv
        self._configured = False  # set_up ran: its publishers are lifecycle publishers
        self._halt_reason = None  # why the node deactivated itself, until activated again
        self._receive_policy = DEFAULT_POLICY
        Node.__init__(self, NODE_NAME, **kwargs)
        LifecycleNodeMixin.__init__(self)
        self._bare = self._entities()  # the bare node's: kept at cleanup
        self._bare_parameters = set(self._parameters)

    @property
    def active(self):
        """Whether the node is in the Active state."""
        return self._state_machine.current_state[1] == 'active'

    def _entities(self):
        """Return the node's entities: publishers, subscriptions, services, clients, timers."""
        return {
            'publisher': list(self._publishers),
            'subscription': list(self._subscriptions),
            'service': list(self._services),
            'client': list(self._clients),
            'timer': list(self._timers),
        }

    def create_publisher(self, *args, **kwargs):
        """Create the valve's publishers as lifecycle publishers: silent unless active."""
        if not hasattr(self, '_managed_entities'):  # Node.__init__'s own: /parameter_events
            return Node.create_publisher(self, *args, **kwargs)
        return self.create_lifecycle_publisher(*args, **kwargs)

    def set_parameters_atomically(self, parameter_list):
        """Unconfigured: the bare node's parameters only (use_sim_time); else as valve_node."""
        if not self._configured:
            return Node.set_parameters_atomically(self, parameter_list)
        return super().set_parameters_atomically(parameter_list)

    def _create_tick_timer(self):
        timer = super()._create_tick_timer()
        if not self.active:  # a new publish_rate while inactive: it ticks from activate on
            timer.cancel()
        return timer

    def use_receive_thread_policy(self, policy):
        """Put the middleware's receive threads under policy, from configure on."""
        self._receive_policy = policy
        if self._configured:
            super().use_receive_thread_policy(policy)

    def publish_fault_status(self):
        """Publish the faults in effect (when active; activate publishes them again)."""
        if self.active:
            super().publish_fault_status()

    # --- transitions ----------------------------------------------------------------------

    @logged('configure')
    def on_configure(self, state):
        """Read and check parameters and files, load the kernels, solve the steady state."""
        self._configured = True
        self.set_up(self._argv)
        self._tick_timer.cancel()
        super().use_receive_thread_policy(self._receive_policy)
        return super().on_configure(state)

    @logged('activate')
    def on_activate(self, state):
        """Re-solve the steady state at the present inputs, then tick and publish."""
        self.take_inputs()
        self.model.reset(self.inlet_flow, self.tank_pressure)  # SteadyStateError: ERROR
        if self.model.time_ns is not None:  # the time inactive is not integrated
            self.model.start(self.get_clock().now().nanoseconds)
        self.status.previous_slot_ns = None
        self._halt_reason = None
        result = super().on_activate(state)
        self._tick_timer.reset()
        self.publish_fault_status()
        self.get_logger().info(
            f'active at the steady state of {self.inlet_flow:g} m^3/s: '
            f'p_s = {self.model.state[P_S]:.6g} Pa (gauge)'
        )
        return result

    @logged('deactivate')
    def on_deactivate(self, state):
        """Stop ticking and hold the state; a halt's reason goes on /diagnostics first."""
        self._tick_timer.cancel()
        if self._halt_reason is not None:
            self.diagnostics.publish()
            self.diagnostics.publisher.publish(self._halt_report())
        return super().on_deactivate(state)

    @logged('cleanup')
    def on_cleanup(self, state):
        """Undo the configuration: back to the bare node."""
        self._tear_down()
        return super().on_cleanup(state)

    @logged('shutdown')
    def on_shutdown(self, state):
        """Undo the configuration, if any, from whichever state."""
        self._tear_down()
        return super().on_shutdown(state)

    @logged('error processing')
    def on_error(self, state):
        """Undo what a failed transition left, so that the node is unconfigured again."""
        self._tear_down()
        return super().on_error(state)

    def _tear_down(self):
        """Destroy what set_up made: entities, parameters, the schedule loader."""
        if not self._configured:
            return
        if getattr(self, 'schedule_loader', None) is not None:
            self.schedule_loader.close()
        if getattr(self, 'parameters', None) is not None:
            self.remove_pre_set_parameters_callback(self.parameters.complete)
            self.remove_on_set_parameters_callback(self.parameters.check)
            self.remove_post_set_parameters_callback(self.parameters.apply)
        clock_subscription = getattr(self._time_source, '_clock_sub', None)  # kept
        for kind, entities in self._entities().items():
            destroy = getattr(self, f'destroy_{kind}')
            for entity in entities:
                if entity not in self._bare[kind] and entity is not clock_subscription:
                    if entity in self._managed_entities:
                        self._managed_entities.discard(entity)
                    destroy(entity)
        # undeclare_parameter refuses read-only parameters; the node declares them anew
        for name in set(self._parameters) - self._bare_parameters:
            del self._parameters[name]
            del self._descriptors[name]
        self.inlet_subscription = self.tank_subscription = None
        self.stamped_subscriptions = ()
        self.parameters = None
        self._configured = False

    # --- the halt path --------------------------------------------------------------------

    def _tick(self):
        # A timer call the executor collected before a transition that stopped the ticks
        # (its timer cancelled, or destroyed by shutdown) still comes: nothing to tick.
        if not self.active:
            return
        super()._tick()
        reason = self._halting_reason()
        if reason is not None and self.active:
            self._halt_reason = reason
            self.get_logger().error(f'deactivating: {reason}')
            self.trigger_deactivate()

    def _halting_reason(self):
        """Return why the node must stop ticking (overpressure, a halted model), or None."""
        if self.injection.overpressure:
            return (
                f'overpressure: p_s = {self.model.state[P_S]:.6g} Pa (gauge) reached '
                f"supply_pressure_limit = {self.model.params['supply_pressure_limit']:g} Pa"
            )
        if self.model.halted is not None:
            return f'the model halted: {self.model.halted}'
        return None

    def _halt_report(self):
        """Return the /diagnostics report of a deactivation by the node itself."""
        status = DiagnosticStatus(
            level=DiagnosticStatus.ERROR,
            name=diagnostics.status_name(self, LIFECYCLE_TASK),
            message=f'deactivated itself: {self._halt_reason}',
            hardware_id=self.hardware_id,
            values=[
                KeyValue(key='lifecycle_state', value='inactive'),
                KeyValue(key='reason', value=self._halt_reason),
                KeyValue(key='model_time_ns', value=str(self.model.time_ns)),
            ],
        )
        report = DiagnosticArray(status=[status])
        report.header.stamp = self.get_clock().now().to_msg()
        return report


def parse_arguments(args):
    """managed_valve_node's own command line (ROS arguments removed)."""
    parser = argparse.ArgumentParser(
        prog='managed_valve_node',
        description='The virtual relief valve as a managed (lifecycle) ROS 2 node; it starts '
        'unconfigured: configure and activate it through ~/change_state (docs/valve_node.md).',
    )
    parser.add_argument('--executor', choices=spinning.EXECUTORS,
                        default=spinning.DEFAULT_EXECUTOR,
                        help=f'rclpy executor that runs the node (default '
                        f'{spinning.DEFAULT_EXECUTOR})')
    parser.add_argument('--receive-threads', choices=POLICIES, default=DEFAULT_POLICY,
                        help="scheduling of the middleware receive threads, as valve_node's")
    parser.add_argument('--autostart', action='store_true',
                        help='configure and activate at once (for a bench without a '
                        'lifecycle manager); a failure leaves the node unconfigured')
    return parser.parse_args(remove_ros_args(sys.argv if args is None else args)[1:])


def main(args=None):
    """Run managed_valve_node until SIGINT or SIGTERM; returns the exit code."""
    options = parse_arguments(args)
    stop = spinning.init(args)
    node = ManagedReliefValveNode(sys.argv if args is None else args)
    try:
        node.get_logger().info(f'unconfigured; executor: {options.executor}')
        node.use_receive_thread_policy(options.receive_threads)
        if options.autostart and node.trigger_configure() == TransitionCallbackReturn.SUCCESS:
            node.trigger_activate()
        spinning.spin_until(node, spinning.EXECUTORS[options.executor](), stop)
    finally:
        node._tear_down()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
