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
A suite of bench scenarios on one valve_node: `valve-sim scenario run DIR` (or FILE FILE ...).

valve_node starts once (SuiteValve) and, before each scenario, is restarted in place
(ros.valve_restart, ~/restart): every parameter back to its start-up value with the
scenario's over it, faults, sensors and schedule as its file says, the exact steady
state of its initial inputs, a new time base from the first /clock. Each scenario gets
its own analyser_node, hence its own bag, in its own folder (NN_<name>/), and its
reports there (ros.scenario_runner.report_run); the suite writes summary.txt and one
JUnit file with a testsuite per scenario. A new valve_node starts for a scenario whose
read-only start values differ (its params_file, a tank_pressure input or none: the
lockstep inputs), and after any scenario that did not complete (a node died or
halted, a timeout, a refused event or restart): that one ends as an error case, the
next starts on fresh nodes.
"""

from valve_sim.core.errors import NodeExitError
from valve_sim.core.output_files import make_folder, safe_name
from valve_sim.core.parameter_sections import node_fqn
from valve_sim.core.parameters import NODE_NAME
from valve_sim.ros import node_command
from valve_sim.ros.lockstep import lockstep_parameters
from valve_sim.ros.node_processes import NodeProcesses
from valve_sim.ros.scenario_runner import analyser_parameters, READY_TIMEOUT, report_run
from valve_sim.ros.valve_restart import request_restart


class ScenarioNodes:
    """One scenario's processes in a suite: the suite's valve_node, its own analyser_node."""

    def __init__(self, valve, analyser):
        self.valve, self.analyser = valve, analyser
        self.folder = analyser.folder
        self.processes = {**valve.processes, **analyser.processes}  # by name, as NodeProcesses

    def check(self, what):
        """Raise NodeExitError if either node ended (while waiting for what)."""
        self.valve.check(what)
        self.analyser.check(what)

    def log(self, name):
        return (self.valve if name == 'valve_node' else self.analyser).log(name)

    def stop(self):
        """Stop the scenario's analyser_node (SIGINT): its bag closes; valve_node runs on."""
        self.analyser.stop()


def start_values(scenario):
    """Return what only a new valve_node can change: its ROS arguments and lockstep inputs."""
    return (str(scenario.params_file or ''), 'tank_pressure' in scenario.inputs)


class SuiteValve:
    """
    The valve_node of a suite, in an rclpy context of the suite's: started, restarted, stopped.

    starts: how many valve_node processes the suite started.
    """

    def __init__(self):
        import rclpy

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.processes, self.key, self.starts = None, None, 0

    def start(self, scenario, folder):
        """
        Return ScenarioNodes for scenario: its analyser_node recording into folder.

        valve_node is started (its log in folder) unless one with the scenario's start
        values runs.
        """
        key = start_values(scenario)
        if self.processes is not None and key != self.key:
            self.stop()
        if self.processes is None:
            params_file, tank = key
            self.processes = NodeProcesses(folder, {'valve_node': node_command(
                'valve_node', parameters=lockstep_parameters(tank),
                ros_args=['--params-file', params_file] if params_file else [])})
            self.key, self.starts = key, self.starts + 1
        analyser = NodeProcesses(folder, {'analyser_node': node_command(
            'analyser_node', parameters={'output_dir': folder,
                                         **analyser_parameters(scenario)})})
        return ScenarioNodes(self.processes, analyser)

    def restart(self, driver, scenario):
        """Restart valve_node at the scenario's start (its parameters over the start-up ones)."""
        request_restart(driver, node_fqn('', NODE_NAME), scenario.parameters, READY_TIMEOUT)

    def stop(self):
        """Stop valve_node (SIGINT); returns why it did not end cleanly, or None."""
        processes, self.processes = self.processes, None
        if processes is None:
            return None
        try:
            processes.stop()
        except NodeExitError as error:
            return str(error)
        return None

    def close(self):
        """Stop valve_node and the suite's rclpy context."""
        try:
            return self.stop()
        finally:
            self.context.try_shutdown()


def scenario_folders(scenarios, out):
    """Return a folder in out for each scenario: NN_<name>, in the suite's order."""
    width = len(str(len(scenarios)))
    return [make_folder(out / f'{index:0{width}d}_{safe_name(scenario.name)}')
            for index, scenario in enumerate(scenarios, 1)]


def run_suite(scenarios, out, rate=None, wait_topics=(), junit=None, progress=print,
              ticks_per_clock=None, flow_topic=None):
    """
    Run scenarios one after the other on a SuiteValve; returns (records, paths, starts).

    out: the suite's folder (created); each scenario's outputs in scenario_folders();
    junit: the suite's JUnit file (default out/junit.xml); paths: the summary's and
    JUnit file's; starts: the valve_node processes started; flow_topic: as
    scenario_runner.run_scenario's, for every scenario.
    """
    from valve_sim.analysis.scenarios.report import write_suite_reports

    records = []
    valve = SuiteValve()
    try:
        for scenario, folder in zip(scenarios, scenario_folders(scenarios, out)):
            progress(f'{scenario.name} ({len(records) + 1} of {len(scenarios)}): {folder}')
            record, _, error = report_run(scenario, folder, rate, wait_topics, None, progress,
                                          ticks_per_clock, flow_topic=flow_topic, valve=valve)
            if error is not None:  # the next starts on fresh nodes
                progress(f'{scenario.name}: ERROR {record.error}; valve_node starts again')
                problem = valve.stop()
                if problem:
                    record.error += f'; {problem}'
            records.append(record)
    finally:
        problem = valve.close()
    if problem and records:  # the last scenario's valve_node did not stop cleanly
        records[-1].error = (records[-1].error + '; ' if records[-1].error else '') + problem
    return records, write_suite_reports(records, out, junit), valve.starts
