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
parameters, analyser_node recording into the output folder), waits until the analyser
records every topic of the valve, and drives the valve in steps of up to TICKS_PER_CLOCK
ticks per /clock (Lockstep; one tick per /clock with wait topics), split so that each
input change and event starts a step (batch_starts): the same states as tick by tick.
The inlet flow of each tick is published before it (and the tank pressure, when the
scenario gives one: its gauge value + ambient_pressure, as the topic is absolute,
stamped with the tick's start), each event's parameter changes applied after the
state of the tick it falls on. Then it waits until the analyser reports
(on /diagnostics) that it has recorded every state, since in lockstep the valve runs
ahead of the analyser's drain, stops both nodes with SIGINT, reads the bag the
analyser closed, checks that it holds every state of the run, and judges
the expectations on it (valve_sim.analysis.expectations). The outputs are written by
valve_sim.analysis.scenario_report.
"""

from dataclasses import dataclass, field
import time

import numpy as np

from valve_sim.analysis.expectations import evaluate
from valve_sim.core.errors import IncompleteRunError
from valve_sim.recording.tick_bags import tick_series
from valve_sim.recording.valve_topics import TICK_TOPICS
from valve_sim.ros.analyser_node import NODE_NAME as ANALYSER, RECORDING_TASK
from valve_sim.ros.clock_jumps import TICKS_PER_CLOCK
from valve_sim.ros.lockstep import Lockstep, NS_PER_S, START_NS
from valve_sim.ros.node_processes import start_valve_and_analyser


RECORDED = (*TICK_TOPICS, 'inlet_flow')  # what the analyser must record before the first tick
READY_TIMEOUT = 180.0  # [s] start-up (a cold kernel compile on a loaded machine) and discovery
# The analyser's queue per topic: in lockstep the valve may run ahead of the analyser's
# drain for as long as this lasts (100 s of states), and nothing is lost meanwhile.
ANALYSER_QUEUE_DEPTH = 100_000
FLOW_REPUBLISH = 0.02  # [s] of model time: the inputs are published again so, as a bench does
PROGRESS_INTERVAL = 2.0  # [s] of wall time between progress lines
DRAIN_TIMEOUT = 120.0  # [s] for analyser_node to record the states still on their way


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
    start_ns: int = START_NS
    error: str = None  # why the run did not complete

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


def start_nodes(scenario, folder):
    """Start valve_node (on /clock) and analyser_node for the scenario; returns NodeProcesses."""
    ambient = scenario.ambient_pressure
    valve = {'use_sim_time': 'true',
             **{name: ros_value(value) for name, value in scenario.parameters.items()}}
    ros_args = ['--params-file', str(scenario.params_file)] if scenario.params_file else []
    return start_valve_and_analyser(
        folder, valve_parameters=valve, valve_ros_args=ros_args,
        analyser_parameters={'queue_depth': ANALYSER_QUEUE_DEPTH, 'ambient_pressure': ambient})


class AnalyserStatus:
    """analyser_node's latest recording status on /diagnostics, heard by the driver's node."""

    def __init__(self, node):
        from diagnostic_msgs.msg import DiagnosticArray

        self.values = {}
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_status, 10)

    def _on_status(self, array):
        for status in array.status:
            if status.name == f'{ANALYSER}: {RECORDING_TASK}':
                self.values = {pair.key: pair.value for pair in status.values}

    def recording(self, topics):
        """Whether the analyser records each of topics (full names)."""
        return all(f'qos {topic}' in self.values for topic in topics)

    def recorded(self, topics, count):
        """Whether the analyser has recorded at least count messages of each of topics."""
        return all(int(self.values.get(f'messages {topic}', 0)) >= count for topic in topics)


def batch_starts(ticks, breaks, size):
    """
    Return the first tick of each /clock step of a run of ticks ticks, steps of at most size.

    breaks: the ticks before which the driver acts (an event, a new or republished
    input): a step starts at each, so none crosses one and every input and change lands
    on the tick it does with one tick per step.
    """
    bounds = [0, *sorted({tick for tick in breaks if 0 < tick < ticks}), ticks]
    return [tick for start, end in zip(bounds, bounds[1:]) for tick in range(start, end, size)]


def apply_event(driver, scenario, tick, changes):
    """Set an event's parameter changes after the state of tick; refused: IncompleteRunError."""
    try:
        driver.set_parameters(changes)
    except ValueError as error:
        raise IncompleteRunError(f'the event at {tick * scenario.period_ns / NS_PER_S:g} '
                                 f's: {error}') from None


def drive(scenario, driver, progress, ticks_per_clock=TICKS_PER_CLOCK):
    """Run the scenario's ticks on a connected Lockstep; returns the wall time [s] it took."""
    flows = scenario.inputs['inlet_flow'].sample(scenario.tick_times())
    tank = scenario.inputs.get('tank_pressure')
    tanks = None if tank is None else tank.sample(scenario.tick_times()) + (
        scenario.ambient_pressure)  # [Pa absolute], as the topic takes it
    events = scenario.event_ticks()
    republish = max(round(FLOW_REPUBLISH * NS_PER_S / scenario.period_ns), 1)
    breaks = {*events, *range(0, scenario.ticks, republish), *change_ticks(flows)}
    if tanks is not None:
        breaks.update(change_ticks(tanks))
    starts = batch_starts(scenario.ticks, breaks, ticks_per_clock)
    driver.set_flow(flows[0])
    if tanks is not None:
        driver.set_tank_pressure(tanks[0], START_NS)
    driver.start(START_NS, scenario.period_ns)
    started = last_report = time.monotonic()
    for tick, end in zip(starts, [*starts[1:], scenario.ticks]):
        if tick in events:
            apply_event(driver, scenario, tick, events[tick])
        if flows[tick] != driver.flow or tick % republish == 0:
            driver.set_flow(flows[tick])
        if tanks is not None and (tanks[tick] != driver.tank or tick % republish == 0):
            driver.set_tank_pressure(tanks[tick], driver.clock_ns)
        driver.tick(end - tick)
        if time.monotonic() - last_report > PROGRESS_INTERVAL:
            last_report = time.monotonic()
            model = end * scenario.period_ns / NS_PER_S
            progress(f't = {model:.3f} s of {scenario.duration:g} s '
                     f'({model / (last_report - started):.2f}x real time)')
    if scenario.ticks in events:
        apply_event(driver, scenario, scenario.ticks, events[scenario.ticks])
    return time.monotonic() - started


def change_ticks(values):
    """Return the ticks whose input value differs from the tick before's."""
    return (np.flatnonzero(values[1:] != values[:-1]) + 1).tolist()


def check_complete(series, scenario, start_ns):
    """Raise IncompleteRunError unless the bag holds a state of every tick, none else."""
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


def run_scenario(scenario, folder, rate=None, wait_topics=(), progress=print,
                 ticks_per_clock=None):
    """
    Run a BenchScenario in folder (created); returns its RunRecord with the checks judged.

    rate: model time per wall time to keep to at most (None: as fast as it goes);
    wait_topics: topics other use_sim_time nodes publish once per tick;
    ticks_per_clock: tick periods per /clock step at most (None: TICKS_PER_CLOCK, or 1
    with wait topics, whose nodes must see every tick's /clock). Raises the
    errors of a run that cannot complete (a node died, a refused event, a timeout,
    an incomplete bag), after stopping both nodes.
    """
    import rclpy

    record = RunRecord(scenario, folder)
    processes = start_nodes(scenario, folder)
    context = rclpy.Context()
    rclpy.init(context=context)
    driver = None
    try:
        driver = Lockstep(context, processes=processes, rate=rate,
                          tank='tank_pressure' in scenario.inputs)
        progress('waiting for valve_node and analyser_node (valve_node loads or compiles its '
                 'kernels first)')
        driver.connect(wait_topics, READY_TIMEOUT)
        status = AnalyserStatus(driver.node)
        recorded = RECORDED + (('tank_pressure',) if 'tank_pressure' in scenario.inputs else ())
        driver.spin_until(lambda: status.recording(map(driver.node.resolve_topic_name,
                                                       recorded)),
                          'analyser_node recording every topic', READY_TIMEOUT)
        progress(f'running {scenario.duration:g} s of model time in lockstep'
                 + (f' at {rate:g}x real time at most' if rate else ' as fast as it goes'))
        record.wall_s = drive(scenario, driver, progress, ticks_per_clock or (
            1 if wait_topics else TICKS_PER_CLOCK))
        # In lockstep the valve runs ahead of the analyser's drain: stopping it now would
        # lose the states still on their way. Its status (once a second) says when it has all.
        progress('waiting for analyser_node to record every state')
        driver.spin_until(lambda: status.recorded(map(driver.node.resolve_topic_name,
                                                      TICK_TOPICS), scenario.ticks + 1),
                          f'analyser_node recording all {scenario.ticks + 1} states',
                          DRAIN_TIMEOUT)
    finally:
        if driver is not None:
            driver.close()
        context.try_shutdown()
        progress('stopping both nodes (SIGINT)')
        processes.stop()
    record.bag = next(iter(sorted(folder.glob('*.mcap'))))
    record.series = tick_series(record.bag, start_ns=START_NS,
                                ambient_pressure=scenario.ambient_pressure)
    check_complete(record.series, scenario, START_NS)
    record.steps = record.series.steps(events=[(event.time_ns / 1e9, event.changes)
                                               for event in scenario.events])
    record.checks = evaluate(scenario.expectations, record.series,
                             scenario.supply_pressure_limits(), record.steps)
    return record


def run_and_report(scenario, folder, rate=None, wait_topics=(), junit=None, progress=print,
                   ticks_per_clock=None):
    """
    Run a scenario and write its reports (scenario_report); returns (RunRecord, paths).

    A run that cannot complete still gets its JUnit file, with the error as its one
    case; the error is then raised again.
    """
    from valve_sim.analysis.scenario_report import junit_document, write_junit, write_reports
    from valve_sim.core.errors import USER_ERRORS

    started = time.monotonic()
    try:
        record = run_scenario(scenario, folder, rate, wait_topics, progress, ticks_per_clock)
    except (*USER_ERRORS, TimeoutError, RuntimeError) as error:
        write_junit(junit_document(scenario, [], time.monotonic() - started, str(error)),
                    folder, junit)
        raise
    return record, write_reports(record, junit)
