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
analyser_node: records valve_node's topics to MCAP and measures every inlet-flow step live.

It records as rosbag2 does.

  sub  every topic of the parameter `topics` (relative names resolve in the node's
       namespace), serialized, of whatever type the graph reports for it; by default
       /parameter_events too (rcl_interfaces/msg/ParameterEvent, every node's parameter
       changes, recorded whole as rosbag2 would) and fault_status: a change of valve_node's
       settings there (a node in the namespace of the supply-pressure topic) that changes
       the model ends a step's window (analysis.steps.input_events, docs/measures.md)
  pub  step_measures   diagnostic_msgs/msg/DiagnosticArray, reliable, transient local:
       one message per measured step, header.stamp = t_step, one DiagnosticStatus
       (name "<node name>: step measures", hardware_id = the parameter hardware_id,
       level OK, or WARN when a measure is undefined) with one KeyValue per measure
       (P_o_percent ... T_s_ms: the number, or "none"), "<measure>_reason" for
       each undefined one, and t_step_s, direction (+1 / -1), flow_before_m3_s,
       window_s, note (a truncated window) and bag (the file it was recorded in).
  pub  /diagnostics    diagnostic_msgs/msg/DiagnosticArray, every status_period (1 s):
       "<node name>: recording": the file, the messages recorded per topic and, for a topic with
       one publisher, the messages lost on the way (gaps in its publication
       sequence numbers), the QoS of each subscription ("qos /topic":
       reliable/volatile ...); ERROR once a wanted topic cannot be recorded (its type
       is unknown here), else WARN while a topic has no message yet, once any was
       lost, while a recorded topic also has publishers of another type ("other types
       on /topic": those are not recorded; the type the analysis reads is), or once a
       /clock message was refused ("refused /clock messages": a time the node cannot
       represent, ignored), else OK. Names and hardware_id as diagnostic_updater has
       them (valve_sim.ros.diagnostics).

One recording per run: output_dir/valve_<date>-<time>.mcap, and beside it
<same name>.measures.json ({"bag", "steps"}, step_analysis.MeasuresFile), to
which each step is appended. With bag_folder:=true a rosbag2 bag folder instead:
output_dir/valve_<date>-<time>/ holding valve_<date>-<time>_0.mcap, its
.measures.json and, once closed, metadata.yaml.

QoS, as rosbag2 chooses it: a topic is subscribed once it has a publisher; reliable if
every publisher is reliable, else best effort (so a SensorDataQoS publisher is heard);
transient local if every publisher is, else volatile. The log and the recording status
name the QoS of each topic; the bag keeps the publishers' offers.

How nothing is lost. Subscriptions have a deep queue (queue_depth per topic, 1 s at
1 kHz by default), filled by the middleware's own threads; a reliable publisher's
messages are not dropped on the way. The
executor (rclpy's EventsExecutor where there is one, as valve_node's) never runs them:
the node leaves them out of the subscriptions it gives an executor. A timer every
drain_period takes all waiting messages of every topic in one go (valve_sim.ros.raw_take,
as valve_node takes its inputs), writes them and feeds the analysis, which reads the
analysed fields from the CDR bytes (valve_sim.recording.cdr.read_message) instead of
building rclpy messages; taking them directly costs a fraction of a callback per
message. Every flush_interval the open chunk is completed and handed to the
operating system, so a hard kill loses at most that much. SIGINT and SIGTERM
end the spin; the node then takes what is still queued, measures (and
publishes) the open steps on what it has, and closes the file.
"""

import argparse
import os
from pathlib import Path
import sys
import textwrap
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import IntegerRange, ParameterDescriptor
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.utilities import remove_ros_args
from valve_sim.analysis.steps.signals import REQUIRED, ROLE, SignalMap
from valve_sim.core.catalogue import ANALYSER_DOUBLES, ANALYSER_SPECS
from valve_sim.core.errors import InputFileError, OutputFileError, USER_ERRORS
from valve_sim.core.output_files import make_folder
from valve_sim.recording.bag import BagWriter
from valve_sim.recording.valve_topics import PARAMETER_EVENTS_TOPIC
from valve_sim.ros import analyser_restart, diagnostics, spinning
from valve_sim.ros.clock_guard import GuardedTimeSource
from valve_sim.ros.measures_publisher import MEASURES_QOS, StepMeasures
from valve_sim.ros.recorder import Recorder
from valve_sim.ros.ros_parameters import declare


NODE_NAME = 'valve_analyser'
DEFAULT_TOPICS = [
    'inlet_flow',
    'inlet_flow_stamped',  # the lockstep drivers' inlet flow (valve_sim.ros.lockstep_inputs)
    'applied_inlet_flow',
    'supply_pressure',
    'intermediate_pressure',
    'pilot_pressure',
    'poppet_chamber_pressure',
    'joint_states',
    '/diagnostics',
    'fault_status',  # valve_node's faults and sensor settings, each change (docs/faults.md)
    'tank_pressure',  # the second input, if a bench sends it, and what the valve applied
    'applied_tank_pressure',
    'relief_flow',
    PARAMETER_EVENTS_TOPIC,  # every node's parameter changes: valve_node's end a window
]
# Recorded once published, never waited for: only a bench with a back pressure sends it.
OPTIONAL_TOPICS = ('tank_pressure', 'inlet_flow_stamped')
# The signals measured: the required ones, and the tank's pressure where it is recorded (the
# measures then take the supply pressure above the tank, step_analysis).
ANALYSED = REQUIRED + ('tank_pressure',)
RECORDING_TASK = 'recording'
DISCOVERY_PERIOD = 0.1  # [s] how often topics not yet seen are looked for (as rosbag2 does)
# The node's own doubles (read-only), from the parameter catalogue: step_threshold,
# step_merge_time, drain_period, flush_interval, status_period. It declares them after
# ambient_pressure
# (ANALYSER_DOUBLES: by default the standard atmosphere).
DOUBLE_PARAMETERS = ANALYSER_SPECS
# Every parameter the node declares, but hardware_id (valve_sim.ros.diagnostics): the
# node declares these tables, and --help and the launch file's check list them.
PLAIN_PARAMETERS = {  # name: (default, description, descriptor constraints)
    'topics': (
        DEFAULT_TOPICS,
        "topics to record (relative names resolve in the node's namespace); the analysed "
        'topics are always recorded',
        {},
    ),
    'output_dir': ('.', 'folder of the recordings (created if missing)', {}),
    'bag_folder': (
        False,
        'record a rosbag2 bag folder (metadata.yaml + .mcap) instead of a single .mcap',
        {},
    ),
    'queue_depth': (
        1000,
        'reliable subscription queue per topic [messages]',
        {'integer_range': [IntegerRange(from_value=10, to_value=1_000_000, step=1)]},
    ),
    **{
        f'{name}_{kind}': (
            getattr(ROLE[name], 'topic' if kind == 'topic' else 'joint'),
            f'{"topic" if kind == "topic" else "JointState joint"} of the {ROLE[name].meaning}',
            {},
        )
        for name in ANALYSED
        for kind in ('topic', 'joint')
        if kind == 'topic' or ROLE[name].joint
    },
}


class ValveAnalyser(Node):
    """
    analyser_node: a recorder of the configured topics to one MCAP file, and a measures publisher.

    The recorder (valve_sim.ros.recorder.Recorder) hands the analysed topics' messages to
    the measures publisher (valve_sim.ros.measures_publisher.StepMeasures), which
    measures every step of the applied inlet flow; the node declares the parameters,
    runs both on its timers and publishes the recording status.
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self.clock_guard = GuardedTimeSource.install(self)
        self.start_settings = self._declare_parameters()
        self.hardware_id = diagnostics.declare_hardware_id(self)
        self.measures_publisher = self.create_publisher(DiagnosticArray, 'step_measures',
                                                        MEASURES_QOS)
        self.parameter_clients = {}  # kept across recordings (start_parameters)
        self.bag, self.measures, self.recorder = self.new_recording(self.start_settings)
        self.status_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # On the steady clock: recording must not stop while a simulation's /clock pauses.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(DISCOVERY_PERIOD, lambda: self.recorder.discover(), clock=steady)
        self.drain_timer = self.create_timer(self.start_settings['drain_period'],
                                             lambda: self.recorder.drain(), clock=steady)
        self.status_timer = self.create_timer(self.start_settings['status_period'],
                                              self._publish_status, clock=steady)
        analyser_restart.serve(self)

    def new_recording(self, settings):
        """
        Open a new recording of settings ({parameter: value}); returns (bag, measures, recorder).

        Raises OutputFileError if its file cannot be created (nothing else changes then).
        """
        signal_map = SignalMap(
            topics={role: self.resolve_topic_name(settings[f'{role}_topic']) for role in ANALYSED},
            joints={role: settings[f'{role}_joint'] for role in ANALYSED if ROLE[role].joint},
            ambient_pressure=settings['ambient_pressure'],
        )
        wanted = dict.fromkeys(
            [self.resolve_topic_name(t) for t in settings['topics']]
            + list(signal_map.topics.values())
        )
        optional = {self.resolve_topic_name(topic) for topic in OPTIONAL_TOPICS}
        bag = BagWriter(
            self._new_bag_path(Path(settings['output_dir']), settings['bag_folder']),
            folder=settings['bag_folder'],
            custom_data={'recorded_by': 'valve_sim analyser_node ' + self.hardware_id},
            new=True,
        )
        measures = StepMeasures(self, signal_map, settings['step_threshold'],
                                settings['step_merge_time'], self.hardware_id, bag.path,
                                self.measures_publisher)
        recorder = Recorder(self, bag, wanted, optional, settings['queue_depth'],
                            settings['flush_interval'], measures,
                            parameter_clients=self.parameter_clients)
        self.get_logger().info(f'recording {", ".join(wanted)} to {bag.path}')
        return bag, measures, recorder

    def restart(self, settings, recording):
        """
        Close the recording as at shutdown; go on with recording, new (bag, measures, recorder).

        settings: the new recording's parameters. Returns the error met closing the old
        one (its file then abandoned as it is on disk), or None.
        """
        try:
            self.close()
            problem = None
        except OSError as error:
            problem = self.write_failure(error)
            self.get_logger().error(str(problem))
        kept = self.recorder.handed_over()
        self.bag, self.measures, self.recorder = recording
        self.recorder.kept = kept
        self.drain_timer.timer_period_ns = round(settings['drain_period'] * 1e9)
        self.status_timer.timer_period_ns = round(settings['status_period'] * 1e9)
        self.clock_guard.restart()  # a new time base, as before the first /clock
        self.recorder.discover()  # the kept subscriptions back in use now
        return problem

    def _declare_parameters(self):
        """Declare the parameters (all read-only: restart to change); returns {name: value}."""
        settings = {}
        for name, (default, description, constraints) in PLAIN_PARAMETERS.items():
            descriptor = ParameterDescriptor(
                name=name, description=description, read_only=True, **constraints
            )
            settings[name] = self.declare_parameter(name, default, descriptor).value
        for spec in ANALYSER_DOUBLES:
            settings[spec.name] = declare(self, spec)
        return settings

    @staticmethod
    def _new_bag_path(folder, bag_folder):
        """
        Return a new file name (or bag folder name) in folder (created).

        Raises OutputFileError, naming the parameter, if folder cannot be created.
        """
        try:
            make_folder(folder)
        except OutputFileError as error:
            raise OutputFileError(f"parameter 'output_dir': {error}") from error
        stem, suffix = time.strftime('valve_%Y%m%d-%H%M%S'), '' if bag_folder else '.mcap'
        path, k = folder / f'{stem}{suffix}', 1
        while os.path.lexists(path):
            k += 1
            path = folder / f'{stem}_{k}{suffix}'
        return path

    @property
    def subscriptions(self):
        """
        Return the subscriptions an executor runs: none of the recorded topics', drain takes them.

        Both executors ask the node for these (the EventsExecutor ignores callback groups).
        """
        taken = self.recorder.subscriptions
        return [s for s in super().subscriptions if s not in taken]

    def _publish_status(self):
        """Publish the recording status on /diagnostics (Recorder.status)."""
        level, message, values = self.recorder.status(self.measures.count,
                                                      self.clock_guard.refused)
        status = DiagnosticStatus(
            level=level,
            name=diagnostics.status_name(self, RECORDING_TASK),
            hardware_id=self.hardware_id,
            message=message,
            values=[KeyValue(key=key, value=value) for key, value in values.items()],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.status_publisher.publish(array)

    def write_failure(self, error):
        """
        Close what can be closed after a write error (a full disk); return the error to report.

        The bag keeps every chunk completed before the error, and no summary.
        """
        self.bag.abandon()
        return InputFileError(
            f'cannot write {error.filename or self.bag.path}: {error.strerror or error}. '
            f'Recording stopped after {self.bag.message_count} messages; {self.bag.path} ends '
            f'after its last complete chunk: `valve-sim repair {self.bag.path}` writes a '
            'complete copy of what it holds'
        )

    def close(self):
        """Take what is still queued, measure the open steps on what there is, close the file."""
        self.recorder.drain()
        self.measures.finish()
        self.bag.close()
        self.get_logger().info(
            f'closed {self.bag.path}: {self.bag.message_count} messages, '
            f'{self.measures.count} steps measured'
        )


def record(stop):
    """
    Run a ValveAnalyser until the event stop is set, then close its recording.

    The recording is closed whatever ends the spin; after a write error (OSError) it
    is abandoned as it is on disk.
    """
    node = ValveAnalyser()
    try:
        try:
            spinning.spin_until(node, spinning.EXECUTORS[spinning.DEFAULT_EXECUTOR](), stop)
        finally:
            node.close()
    except OSError as error:
        raise node.write_failure(error) from error
    finally:
        node.destroy_node()


def parameter_names():
    """Return the names of the node's own ROS parameters, from the tables it declares."""
    return [*PLAIN_PARAMETERS, 'ambient_pressure', *(spec.name for spec in DOUBLE_PARAMETERS),
            diagnostics.HARDWARE_ID]


def parse_arguments(args):
    """
    Parse analyser_node's own command line (ROS arguments removed).

    It has no options of its own: --help prints the usage, the parameters and exits 0
    before anything is recorded; anything else is a usage error (exit 2).
    """
    parser = argparse.ArgumentParser(
        prog='analyser_node',
        description=__doc__.strip().splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=textwrap.fill(
            'ROS parameters (read-only, set at start: --ros-args -p NAME:=VALUE or '
            '--params-file FILE): ' + ', '.join(parameter_names()) + '. '
            '`ros2 param describe /valve_analyser NAME` explains each. Example: '
            'analyser_node --ros-args -p output_dir:=/data/recordings',
            width=88,
        ),
    )
    return parser.parse_args(remove_ros_args(sys.argv if args is None else args)[1:])


def main(args=None):
    """
    Run analyser_node until SIGINT or SIGTERM; returns the exit code.

    The node closes its file with the middleware still up, so the last
    measures are still published.
    """
    parse_arguments(args)
    stop = spinning.init(args)
    try:
        record(stop)
    except (*USER_ERRORS, ParameterException) as error:
        rclpy.logging.get_logger(NODE_NAME).fatal(str(error))
        return 1
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
