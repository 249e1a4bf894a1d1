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
Run a bench scenario over DDS: valve_node and analyser_node in lockstep, then the verdict.

run_scenario() starts both nodes (valve_node on use_sim_time with the scenario's
parameters and stamped lockstep inputs, analyser_node recording into the output folder),
waits until the analyser records every topic of the valve, and drives the valve in
steps of up to TICKS_PER_CLOCK ticks per /clock (ros.lockstep; one tick per /clock with
wait topics), split so that each event starts a step, through ros.scenario_stepper
(valve_simulator's too): before each step the inlet flow of each of its ticks that
changes is sent stamped with the tick's start (and the tank pressure, when the scenario
gives one), so a ramp or a sine runs as many ticks per /clock as a step, the same
states as tick by tick; each event's parameter changes are applied after the state of
the tick it falls on. Then it waits until the analyser
reports (on /diagnostics) that it has recorded every state, since in lockstep the valve
runs ahead of the analyser's drain, stops both nodes with SIGINT, reads the bag the
analyser closed, checks that it holds every state of the run and that each tick
applied the flow sent for it, and judges the expectations on it
(valve_sim.analysis.scenarios.expectations). The outputs are written by
valve_sim.analysis.scenarios.report, for a run that failed too (run_and_report): with
what was measured up to the failure, each expectation judged on its own.
"""

from dataclasses import dataclass, field
import importlib
from pathlib import Path
import threading
import time

import numpy as np

from valve_sim.analysis.scenarios.expectations import evaluate
from valve_sim.core.errors import IncompleteRunError, NodeExitError, USER_ERRORS
from valve_sim.recording.tick_bags import tick_series
from valve_sim.recording.valve_topics import TICK_TOPICS
from valve_sim.ros.analyser_node import NODE_NAME as ANALYSER, RECORDING_TASK
from valve_sim.ros.clock_jumps import TICKS_PER_CLOCK
from valve_sim.ros.lockstep import (
    HANDSHAKE, Lockstep, lockstep_parameters, NS_PER_S, START_NS)
from valve_sim.ros.node_processes import start_valve_and_analyser
from valve_sim.ros.scenario_stepper import input_values, ScenarioStepper
from valve_sim.ros.start_parameters import STATUS_KEY as START_PARAMETERS
from valve_sim.ros.valve_inputs import STAMPED_FLOW_TOPIC
from valve_sim.ros.valve_outputs import STATE_QUEUE_DEPTH


# what the analyser must record before the first tick
RECORDED = (*TICK_TOPICS, STAMPED_FLOW_TOPIC)
READY_TIMEOUT = 180.0  # [s] start-up (a cold kernel compile on a loaded machine) and discovery
# The analyser's queue per topic: in lockstep the valve may run ahead of the analyser's
# drain for as long as this lasts (100 s of states), and nothing is lost meanwhile.
ANALYSER_QUEUE_DEPTH = 100_000
PROGRESS_INTERVAL = 2.0  # [s] of wall time between progress lines
DRAIN_TIMEOUT = 120.0  # [s] for analyser_node to record the states still on their way
# [ticks] how far the valve may run ahead of the analyser's recording: half of what valve_node
# keeps for a slow reader, the other half the margin for the status's age (STATUS_PERIOD)
MAX_AHEAD = STATE_QUEUE_DEPTH // 2
# [s] analyser_node's recording status, which the run waits on before its first tick and
# after its last (the default, 1 s, would add up to a second to each)
STATUS_PERIOD = 0.05
PLOTTING = 'valve_sim.analysis.plotting'  # matplotlib: 0.2 s to import


@dataclass
class RunRecord:
    """What a run of a scenario produced and how fast: the series, checks, bag, timing."""

    scenario: object
    folder: object
    bag: object = None
    series: object = None
    checks: list = field(default_factory=list)
    steps: list = field(default_factory=list)
    wall_s: float = 0.0  # [s] of the lockstep stepping
    clock_steps: int = 0  # /clock messages of the stepping (each up to ticks_per_clock ticks)
    start_ns: int = START_NS
    error: str = None  # why the run did not complete
    flows: object = None  # [m^3/s] the inlet flow sent for each tick (a controller's too)
    invariant_alarms: str = ''  # valve_node's invariant alarm counts as last reported

    @property
    def passed(self):
        return self.error is None and bool(self.checks) and all(c.passed for c in self.checks)

    @property
    def speed(self):
        """Model time per wall time of the stepping (the real-time factor)."""
        return self.scenario.duration / self.wall_s if self.wall_s > 0 else None


def ros_value(value):
    """Return a parameter value as valve_node's command line takes it (-p NAME:=VALUE)."""
    return str(value).lower() if isinstance(value, bool) else repr(value)


def valve_arguments(scenario):
    """
    Return valve_node's (parameters, ROS arguments) for a scenario driven by a Lockstep.

    On /clock with stamped inputs (lockstep_parameters()), the scenario's parameters
    and its parameter file.
    """
    parameters = {**lockstep_parameters(tank='tank_pressure' in scenario.inputs),
                  **{name: ros_value(value) for name, value in scenario.parameters.items()}}
    ros_args = ['--params-file', str(scenario.params_file)] if scenario.params_file else []
    return parameters, ros_args


def analyser_parameters(scenario):
    """Return analyser_node's parameters for a scenario (but its output_dir)."""
    return {'queue_depth': ANALYSER_QUEUE_DEPTH, 'ambient_pressure': scenario.ambient_pressure,
            'use_sim_time': 'true',  # the bag's log times: model time
            'status_period': STATUS_PERIOD}


def start_nodes(scenario, folder):
    """Start valve_node (on /clock) and analyser_node for the scenario; returns NodeProcesses."""
    valve, ros_args = valve_arguments(scenario)
    return start_valve_and_analyser(folder, valve_parameters=valve, valve_ros_args=ros_args,
                                    analyser_parameters=analyser_parameters(scenario))


class AnalyserStatus:
    """
    The run's own analyser_node's latest recording status on /diagnostics.

    Its own: the one recording into folder. A status of an analyser recording elsewhere
    (another run's nodes in this ROS domain) is kept in foreign, and check() raises.
    """

    def __init__(self, node, folder):
        from diagnostic_msgs.msg import DiagnosticArray

        self.values, self.folder, self.foreign = {}, Path(folder).resolve(), None
        self.invariant_alarms = ''  # valve_node's ('name: count, ...'), heard on the way
        self.node = node
        self.subscription = node.create_subscription(DiagnosticArray, '/diagnostics',
                                                     self._on_status, 10)

    def close(self):
        """Stop listening (a suite's driver node lives on)."""
        self.node.destroy_subscription(self.subscription)

    def _on_status(self, array):
        for status in array.status:
            if status.name == f'{ANALYSER}: {RECORDING_TASK}':
                values = {pair.key: pair.value for pair in status.values}
                if Path(values.get('file', '')).resolve().parent == self.folder:
                    self.values = values
                else:
                    self.foreign = values.get('file', '?')
            for pair in status.values:
                if pair.key == 'invariant_alarms':
                    self.invariant_alarms = pair.value

    def check(self):
        """Raise IncompleteRunError if another analyser_node answers in this ROS domain."""
        if self.foreign is not None:
            raise IncompleteRunError(
                f'another analyser_node in this ROS domain records to {self.foreign}: '
                'nodes of another run are up here; stop them or run in a domain of its own')

    def recording(self, topics):
        """Whether the analyser records each of topics (full names)."""
        self.check()
        return all(f'qos {topic}' in self.values for topic in topics)

    def read_start_parameters(self):
        """Whether the analyser has read valve_node's start values (ros.start_parameters)."""
        return bool(self.values.get(START_PARAMETERS))

    def recorded(self, topics, count):
        """Whether the analyser has recorded at least count messages of each of topics."""
        self.check()
        return all(int(self.values.get(f'messages {topic}', 0)) >= count for topic in topics)

    def keep_up(self, driver, topics, tick):
        """
        Spin driver while the analyser has recorded fewer states than tick - MAX_AHEAD.

        topics: the tick topics' full names.

        valve_node's tick publishers keep STATE_QUEUE_DEPTH messages that a reader has not
        acknowledged (a reliable keep-last writer drops the oldest beyond): a valve further
        ahead of a starved analyser would lose states, and the run could never complete.
        """
        if not self.recorded(topics, tick - MAX_AHEAD):
            driver.spin_until(lambda: self.recorded(topics, tick - MAX_AHEAD),
                              f'analyser_node recording the states up to tick '
                              f'{tick - MAX_AHEAD}', DRAIN_TIMEOUT)


def drive(scenario, driver, progress, ticks_per_clock=TICKS_PER_CLOCK, record=None,
          flow_reply=None, keep_up=None):
    """
    Run the scenario's ticks on a connected Lockstep (ScenarioStepper); returns the wall time [s].

    record: a RunRecord whose wall_s follows the run (for a run that fails midway);
    flow_reply: the wait topic whose controller supplies the flow (ScenarioStepper);
    keep_up(tick): called before each /clock, waits while the recording lags too far
    behind tick (AnalyserStatus.keep_up).
    """
    stepper = ScenarioStepper(scenario, driver, ticks_per_clock, flow_reply)
    if record is not None:
        record.flows = stepper.flows
    stepper.start()
    started = last_report = time.monotonic()
    while stepper.tick < scenario.ticks:
        if keep_up is not None:
            keep_up(stepper.tick)
        stepper.batch(scenario.ticks)
        if record is not None:
            record.wall_s = time.monotonic() - started
            record.clock_steps += 1
        if time.monotonic() - last_report > PROGRESS_INTERVAL:
            last_report = time.monotonic()
            model = stepper.tick * scenario.period_ns / NS_PER_S
            progress(f't = {model:.3f} s of {scenario.duration:g} s '
                     f'({model / (last_report - started):.2f}x real time)')
    return time.monotonic() - started


def check_complete(series, scenario, start_ns, flows=None):
    """
    Raise IncompleteRunError unless the bag holds a state of every tick, none else.

    Also unless every tick applied the inlet flow sent for it (the same float; flows,
    a tick each: default the scenario's).
    """
    expected = [start_ns + k * scenario.period_ns for k in range(scenario.ticks + 1)]
    if series.stamps_ns.tolist() != expected:
        missing = sorted(set(expected) - set(series.stamps_ns.tolist()))
        raise IncompleteRunError(
            f'the bag holds states at {len(series)} stamps, the run had {len(expected)} ticks'
            + (f'; the first missing at {missing[0] / NS_PER_S:.6f} s' if missing else ''))
    for name in ('main_valve', 'inlet_flow'):  # never in dropout: every tick has them
        gaps = int(series[name].size - (series[name] == series[name]).sum())
        if gaps:
            raise IncompleteRunError(f'the bag lacks {name} at {gaps} of the ticks of the run')
    # tick k applies the value sampled (or sent) for its start
    flows = (input_values(scenario)[0] if flows is None else flows)[:scenario.ticks]
    wrong = np.flatnonzero(series['inlet_flow'][1:] != flows)
    if wrong.size:
        tick = int(wrong[0])
        raise IncompleteRunError(
            f'the tick from {tick * scenario.period_ns / NS_PER_S:.6f} s applied '
            f'{series["inlet_flow"][tick + 1]:g} m^3/s, not the {flows[tick]:g} m^3/s sent for '
            f'it ({wrong.size} such ticks)')


def run_scenario(scenario, folder, rate=None, wait_topics=(), progress=print,
                 ticks_per_clock=None, record=None, flow_topic=None, valve=None):
    """
    Run a BenchScenario in folder (created); returns its RunRecord with the checks judged.

    rate: model time per wall time to keep to at most (None: as fast as it goes);
    wait_topics: topics other use_sim_time nodes publish once per tick;
    ticks_per_clock: tick periods per /clock step at most (None: TICKS_PER_CLOCK, or 1
    with wait topics, whose nodes must see every tick's /clock); record: the RunRecord
    to fill (default: a new one); flow_topic: a wait topic whose controller supplies
    the inlet flow from the second tick on (ros.scenario_stepper); valve: the SuiteNodes
    of a suite (ros.scenario_suite), whose nodes run on, restarted for this scenario
    (else both nodes start here). Raises the errors of a run that cannot
    complete (a node died, a refused event, a timeout, an incomplete bag, another run's
    nodes in the domain), after stopping both nodes (a suite's: its recording closed,
    the suite stops them); record then holds what the run got to (measure_partial reads the rest).
    """
    import rclpy

    record = record or RunRecord(scenario, folder)
    if flow_topic is not None and flow_topic not in wait_topics:
        wait_topics = (*wait_topics, flow_topic)  # each tick waits for the reply too
    processes = start_nodes(scenario, folder) if valve is None else valve.start(scenario, folder)
    if valve is None:
        context = rclpy.Context()
        rclpy.init(context=context)
    driver, status, failed = None, None, True  # failed until the run gets through
    try:
        progress('waiting for valve_node and analyser_node (valve_node loads or compiles its '
                 'kernels first)')
        if valve is None:
            driver = Lockstep(context, processes=processes, rate=rate,
                              tank='tank_pressure' in scenario.inputs)
            driver.connect(wait_topics, READY_TIMEOUT)
        else:  # the suite's driver, connected once; both nodes at the scenario's start
            driver = valve.connect()
            valve.restart(scenario, folder)
        status = AnalyserStatus(driver.node, folder)
        recorded = RECORDED + (('tank_pressure',) if 'tank_pressure' in scenario.inputs else ())
        # valve_node's start values in the bag before any change the run makes
        driver.spin_until(lambda: status.recording(map(driver.node.resolve_topic_name,
                                                       recorded))
                          and status.read_start_parameters(),
                          "analyser_node recording every topic and valve_node's parameters",
                          READY_TIMEOUT)
        inputs = driver.input_publishers()  # matched by both nodes: none sent is lost
        tick_topics = [driver.node.resolve_topic_name(topic) for topic in TICK_TOPICS]
        driver.spin_until(lambda: all(publisher.get_subscription_count() >= 2
                                      for publisher, _ in inputs.values()),
                          'analyser_node subscribed to the inputs', READY_TIMEOUT)
        progress(f'running {scenario.duration:g} s of model time in lockstep'
                 + (f' at {rate:g}x real time at most' if rate else ' as fast as it goes'))
        record.wall_s = drive(scenario, driver, progress, ticks_per_clock or (
            1 if wait_topics else TICKS_PER_CLOCK), record, driver.flow_reply(flow_topic),
            keep_up=lambda tick: status.keep_up(driver, tick_topics, tick))
        # In lockstep the valve runs ahead of the analyser's drain: stopping it now would
        # lose the states still on their way. Its status (each STATUS_PERIOD) says when it has
        # all.
        progress('waiting for analyser_node to record every state')
        driver.spin_until(lambda: status.recorded(tick_topics, scenario.ticks + 1)
                          and all(status.recorded([topic], sent.count)
                                  for topic, (_, sent) in inputs.items()),
                          f'analyser_node recording all {scenario.ticks + 1} states and '
                          'every input sent', DRAIN_TIMEOUT)
        others = driver.node.count_publishers(driver.node.resolve_topic_name(HANDSHAKE)) - 1
        if others > 0:
            raise IncompleteRunError(f'{others} other valve_node(s) in this ROS domain answered '
                                     'the run too: stop them or run in a domain of its own')
        record.invariant_alarms = status.invariant_alarms
        failed = False
    finally:
        if status is not None:
            status.close()
        if valve is None:
            if driver is not None:
                driver.close()
            context.try_shutdown()
        progress('stopping both nodes (SIGINT)' if valve is None
                 else "closing the scenario's recording (analyser_node restarts)")
        # the figure's library imported while the nodes stop (the report draws it next)
        threading.Thread(target=importlib.import_module, args=(PLOTTING,), daemon=True).start()
        try:
            processes.stop()
        except NodeExitError as error:
            if not failed:
                raise
            progress(f'then: {error}')  # the run's own error goes on: it says why
    record.bag = next(iter(sorted(folder.glob('*.mcap'))))
    record.series = tick_series(record.bag, start_ns=START_NS,
                                ambient_pressure=scenario.ambient_pressure)
    check_complete(record.series, scenario, START_NS, record.flows)
    record.steps = record.series.steps(events=scenario.window_events())
    record.checks = judge(scenario, record.series, record.steps)
    return record


def judge(scenario, series, steps):
    """
    Judge each expectation on series (states from t = 0, all or the first ones).

    Raises IncompleteRunError naming the first expectation that cannot be judged, with
    the checks of the others in its checks attribute.
    """
    limits = scenario.supply_pressure_limits()[:len(series)]
    checks, problems = [], []
    for index, expectation in enumerate(scenario.expectations):
        try:
            checks += evaluate([expectation], series, limits, steps)
        except (ValueError, LookupError) as error:
            problems.append(f'expect[{index}] cannot be judged: {error}')
    if problems:
        error = IncompleteRunError('; '.join(problems))
        error.checks = checks
        raise error
    return checks


def measure_partial(record):
    """
    After a failed run: the bag, states, steps and checks of what was recorded, if any.

    Each expectation is judged on the states up to the failure; one that cannot be
    judged (or a bag that cannot be read) adds its reason to record.error.
    """
    bags = sorted(record.folder.glob('*.mcap'))
    if not bags:
        return
    record.bag = bags[0]
    try:
        record.series = tick_series(record.bag, start_ns=START_NS,
                                    ambient_pressure=record.scenario.ambient_pressure)
        record.steps = record.series.steps(events=record.scenario.window_events())
        record.checks = judge(record.scenario, record.series, record.steps)
    except IncompleteRunError as error:
        record.checks = getattr(error, 'checks', [])
        if str(error) not in record.error:
            record.error += f'; {error}'
    except (*USER_ERRORS, ValueError) as error:
        record.error += f'; no states to judge: {error}'


def run_and_report(scenario, folder, rate=None, wait_topics=(), junit=None, progress=print,
                   ticks_per_clock=None, flow_topic=None, valve=None):
    """
    Run a scenario and write its reports (scenarios.report); returns (RunRecord, paths).

    A run that cannot complete still gets every report, with what was measured up to
    the failure and the error (JUnit: the checks and an error case); the error is then
    raised again. valve: as run_scenario's.
    """
    record, paths, error = report_run(scenario, folder, rate, wait_topics, junit, progress,
                                      ticks_per_clock, flow_topic=flow_topic, valve=valve)
    if error is not None:
        raise error
    return record, paths


def report_run(scenario, folder, rate=None, wait_topics=(), junit=None, progress=print,
               ticks_per_clock=None, flow_topic=None, valve=None):
    """Run a scenario, write its reports; returns (RunRecord, paths, the run's error or None)."""
    from valve_sim.analysis.scenarios.report import plot_run, write_reports

    record, error = RunRecord(scenario, folder), None
    try:
        run_scenario(scenario, folder, rate, wait_topics, progress, ticks_per_clock, record,
                     flow_topic=flow_topic, valve=valve)
    except (*USER_ERRORS, TimeoutError, RuntimeError, ChildProcessError) as run_error:
        record.error, error = str(run_error) or type(run_error).__name__, run_error
        measure_partial(record)
    return record, write_reports(record, junit, plot_run if valve is None else valve.plot), error


def lockstep_messages(bag, topics=(*TICK_TOPICS, STAMPED_FLOW_TOPIC, 'tank_pressure')):
    """
    Return {topic: [(log_time, publish_time, CDR bytes)]} of the valve's topics in a bag.

    What two runs of a scenario must record alike: each tick topic's and input's
    messages in order, with their model-time log and publish times (the bag's other
    topics, /diagnostics and fault_status, say how the run went in wall time).
    """
    from valve_sim.recording.bag import BagReader

    wanted = {f'/{topic}' for topic in topics}
    messages = {}
    for channel, _, message in BagReader(bag).messages(wanted):
        messages.setdefault(channel.topic, []).append(
            (message.log_time, message.publish_time, bytes(message.data)))
    return messages
