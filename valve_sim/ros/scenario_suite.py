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

valve_node and analyser_node start once (SuiteNodes), with one Lockstep driver
(connected once, its restart clients kept). Before each scenario both nodes are
restarted in place through their ~/restart services: valve_node and the driver
(Lockstep.restart, ros.valve_restart) with every parameter back to its start-up value
and the scenario's over it, faults, sensors and schedule as its file says, the exact
steady state of its initial inputs, a new time base from the first /clock; then
analyser_node (ros.analyser_restart) into the scenario's folder (NN_<name>/): a bag of
its own, its .measures.json, valve_node's start parameters read after valve_node's
restart (so the restart's parameter changes go to the bag before). When the scenario
has run, analyser_node restarts into a scratch folder of the suite's (deleted at its
end), which closes the scenario's bag before its reports are written
(ros.scenario_runner.report_run; its figure in a thread of the suite's while the next
scenario runs). The suite writes summary.txt and one JUnit file with
a testsuite per scenario. The node logs are in the folder of the scenario that started
the nodes. New nodes start for a scenario whose read-only start values differ (its
params_file, a tank_pressure input or none: the lockstep inputs), and after any
scenario that did not complete (a node died or halted, a timeout, a refused event or
restart): that one ends as an error case, the next starts on fresh nodes.
"""

from concurrent.futures import ThreadPoolExecutor
import copy
import shutil
import tempfile

from valve_sim.core.errors import NodeExitError, ParameterError, WaitTimeoutError
from valve_sim.core.output_files import make_folder, safe_name
from valve_sim.core.parameter_sections import node_fqn
from valve_sim.ros import node_command
from valve_sim.ros.analyser_node import NODE_NAME as ANALYSER
from valve_sim.ros.lockstep import Lockstep, lockstep_parameters
from valve_sim.ros.node_processes import NodeProcesses
from valve_sim.ros.scenario_runner import analyser_parameters, READY_TIMEOUT, report_run


class ScenarioNodes:
    """One scenario's view of the suite's nodes: both run on; stop() closes its recording."""

    def __init__(self, suite):
        self.suite, self.folder = suite, suite.processes.folder
        self.processes = suite.processes.processes  # by name, as NodeProcesses

    def check(self, what):
        """Raise NodeExitError if a node of the suite ended (while waiting for what)."""
        self.suite.processes.check(what)

    def log(self, name):
        return self.suite.processes.log(name)

    def stop(self):
        """
        Close the scenario's bag: analyser_node restarts into the suite's scratch folder.

        Raises NodeExitError if it does not (as a node that does not stop cleanly). Without
        a driver (the nodes never answered) nothing was recorded there.
        """
        if self.suite.driver is None:
            return
        try:
            self.suite.record_into(self.suite.scratch)
        except (ParameterError, WaitTimeoutError) as error:
            raise NodeExitError(f'analyser_node did not close the recording: {error}') from error


def start_values(scenario):
    """Return what only new nodes can change: valve_node's ROS arguments and lockstep inputs."""
    return (str(scenario.params_file or ''), 'tank_pressure' in scenario.inputs)


class SuiteNodes:
    """
    The valve_node and analyser_node of a suite, and its Lockstep driver (ros.lockstep).

    In an rclpy context of the suite's: started, restarted (ros.valve_restart,
    ros.analyser_restart), stopped. The driver is connected once per start of the nodes
    and kept across restarts (Lockstep.restart). rate, wait_topics: as
    scenario_runner.run_scenario's, for every scenario. starts: how many times the suite
    started the nodes.
    """

    def __init__(self, rate=None, wait_topics=()):
        import rclpy

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.rate, self.wait_topics = rate, wait_topics
        self.scratch = tempfile.mkdtemp(prefix='valve-sim-suite-')
        self.processes, self.driver, self.key, self.starts = None, None, None, 0
        # one thread draws each scenario's figure while the next runs (this thread only
        # waits on the nodes meanwhile); nothing else here uses matplotlib
        self.figures, self.drawn = ThreadPoolExecutor(max_workers=1), []

    def plot(self, path, run):
        """Draw run's figure to path in the figure thread (close() waits for it)."""
        from valve_sim.analysis.scenarios.report import plot_run

        self.drawn.append(self.figures.submit(plot_run, path, copy.copy(run)))

    def start(self, scenario, folder):
        """
        Return ScenarioNodes for scenario.

        Both nodes are started (their logs in folder, analyser_node recording into the
        scratch folder) unless nodes with the scenario's start values run.
        """
        key = start_values(scenario)
        if self.processes is not None and key != self.key:
            self.stop()
        if self.processes is None:
            params_file, tank = key
            self.processes = NodeProcesses(folder, {
                'valve_node': node_command(
                    'valve_node', parameters=lockstep_parameters(tank),
                    ros_args=['--params-file', params_file] if params_file else []),
                'analyser_node': node_command(
                    'analyser_node', parameters={**analyser_parameters(scenario),
                                                 'output_dir': self.scratch}),
            })
            self.key, self.starts = key, self.starts + 1
        return ScenarioNodes(self)

    def connect(self):
        """Return the suite's Lockstep driver, connected to the running nodes."""
        if self.driver is None:
            driver = Lockstep(self.context, processes=self.processes, rate=self.rate,
                              tank=self.key[1])
            try:
                driver.connect(self.wait_topics, READY_TIMEOUT)
            except BaseException:
                driver.close()
                raise
            self.driver = driver
        return self.driver

    def restart(self, scenario, folder):
        """Restart valve_node (and the driver) at the scenario's start, then analyser_node."""
        self.driver.restart(scenario.parameters, READY_TIMEOUT)
        self.record_into(folder, scenario.ambient_pressure)

    def record_into(self, folder, ambient_pressure=None):
        """Restart analyser_node: its recording closed, a new one in folder."""
        overrides = {'output_dir': str(folder)}
        if ambient_pressure is not None:
            overrides['ambient_pressure'] = float(ambient_pressure)
        self.driver.request_restart(node_fqn('', ANALYSER), overrides, READY_TIMEOUT)

    def stop(self):
        """Stop both nodes (SIGINT) and the driver; returns why they did not stop cleanly."""
        processes, self.processes = self.processes, None
        if self.driver is not None:
            self.driver.close()
            self.driver = None
        if processes is None:
            return None
        try:
            processes.stop()
        except NodeExitError as error:
            return str(error)
        return None

    def close(self):
        """
        Stop both nodes and the suite's rclpy context; delete the scratch folder.

        Then wait for the figures; raises the error of one that could not be written.
        """
        try:
            return self.stop()
        finally:
            self.context.try_shutdown()
            shutil.rmtree(self.scratch, ignore_errors=True)
            self.figures.shutdown(wait=True)
            for drawn in self.drawn:
                drawn.result()


def scenario_folders(scenarios, out):
    """Return a folder in out for each scenario: NN_<name>, in the suite's order."""
    width = len(str(len(scenarios)))
    return [make_folder(out / f'{index:0{width}d}_{safe_name(scenario.name)}')
            for index, scenario in enumerate(scenarios, 1)]


def run_suite(scenarios, out, rate=None, wait_topics=(), junit=None, progress=print,
              ticks_per_clock=None, flow_topic=None):
    """
    Run scenarios one after the other on SuiteNodes; returns (records, paths, starts).

    out: the suite's folder (created); each scenario's outputs in scenario_folders();
    junit: the suite's JUnit file (default out/junit.xml); paths: the summary's and
    JUnit file's; starts: how many times the nodes were started; flow_topic: as
    scenario_runner.run_scenario's, for every scenario.
    """
    from valve_sim.analysis.scenarios.report import write_suite_reports

    records = []
    if flow_topic is not None and flow_topic not in wait_topics:
        wait_topics = (*wait_topics, flow_topic)  # each tick waits for the reply too
    nodes = SuiteNodes(rate, wait_topics)
    try:
        for scenario, folder in zip(scenarios, scenario_folders(scenarios, out)):
            progress(f'{scenario.name} ({len(records) + 1} of {len(scenarios)}): {folder}')
            record, _, error = report_run(scenario, folder, rate, wait_topics, None, progress,
                                          ticks_per_clock, flow_topic=flow_topic, valve=nodes)
            if error is not None:  # the next starts on fresh nodes
                progress(f'{scenario.name}: ERROR {record.error}; the nodes start again')
                problem = nodes.stop()
                if problem:
                    record.error += f'; {problem}'
            records.append(record)
    finally:
        problem = nodes.close()
    if problem and records:  # the last scenario's nodes did not stop cleanly
        records[-1].error = (records[-1].error + '; ' if records[-1].error else '') + problem
    return records, write_suite_reports(records, out, junit), nodes.starts
