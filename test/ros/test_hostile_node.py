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
valve_node against the rest of the graph: hostile files, clocks and parameter sets.

Anyone on a bench's graph can set a parameter or publish /clock. A wall-clock node
(namespace /hostile) is handed every kind of bad fault schedule live and must go on
publishing; a node on /clock (/hostile_sim) gets clocks it cannot represent, a clock
that jumps back, and changes that an overpressure rolls back, after which its declared
parameters, its model and its diagnostics must agree.
"""

import os
from pathlib import Path
import subprocess
import sys
import threading
import time

from hostile_inputs import FILES, make_file, YAML_TEXTS
import pytest
from valve_harness import running_valve, start_node, TIMEOUT
from valve_sim.core.parameters import config_path, load_parameters
from valve_sim.core.simulation import LITRE_PER_MINUTE
from valve_sim.recording.valve_topics import PRESSURE_TOPICS


pytestmark = [pytest.mark.timeout(600), pytest.mark.usefixtures('valve_node_kernels')]

FLOW = 5.0 * LITRE_PER_MINUTE
PERIOD_NS = 1_000_000
START_S = 10_000  # [s] /clock at the start: room for a jump back by 1000 s
NS_PER_S = 1_000_000_000
POLL_S = 0.05  # [s] how often a wait asks the node again
MAX_STAMP_GAP_NS = 3 * NS_PER_S  # the freezes found took 57 s or for ever; a tick is 1 ms
ABSURD_FLOW = 1.0  # [m^3/s] drives p_s past burst_pressure within a step
LIFTED_MAX_FLOW = 2.0  # [m^3/s] max_inlet_flow that lets ABSURD_FLOW in


def many_events(count):
    """Return a valid schedule of count events, far in the future."""
    return 'events:\n' + ''.join(
        f'  - t: {1000 + i * 1e-3:.3f}\n    set: {{sensor.supply_pressure.noise_std: {i % 7}.0}}\n'
        for i in range(count)
    )


# Bad schedule files, each refused while the node goes on: every hostile file and YAML
# document of hostile_inputs, and schedules too large or wrong in their content.
BAD_SCHEDULES = {
    **FILES,
    **YAML_TEXTS,
    'a 12 MB file of 200,000 events': many_events(200_000),
    '20,000 events in 1 MiB': 'events:\n' + ''.join(
        f'- {{t: {i}, set: {{fault.main_valve_stuck: true}}}}\n' for i in range(20_000)
    ),
    'a value out of range': (
        'events:\n  - t: 0.1\n    set: {fault.damping_orifice_blockage: 1.5}\n'
    ),
    'not a schedule': '- just\n- a list\n',
}

# The counts these tests wait on, five times a second (valve_node's default: once a second).
FAST_DIAGNOSTICS = ('-p', 'diagnostic_updater.period:=0.2')


@pytest.fixture(scope='module')
def wall(context, tmp_path_factory):
    """Yield the wall-clock node and its probe: (process, probe, folder)."""
    folder = tmp_path_factory.mktemp('hostile')
    with running_valve(
        context, folder / 'valve_node.log', *FAST_DIAGNOSTICS, namespace='/hostile'
    ) as (process, probe):
        yield process, probe, folder


def counter(probe, key, at_least):
    """Wait for a diagnostics report with key >= at_least; return its values."""
    return probe.wait_for_diagnostics(
        lambda values: int(values[key]) >= at_least, f'{key} >= {at_least}'
    )


def largest_stamp_gap(probe, start):
    """Return the largest gap [ns] between consecutive supply_pressure stamps from row start."""
    with probe.condition:
        stamps = [stamp for stamp, _ in probe.pressures['supply_pressure'][start:]]
    return max((b - a for a, b in zip(stamps, stamps[1:])), default=0)


def schedule_in_effect(probe):
    """Return fault_schedule once no file is being read (it is set back if one was refused)."""
    deadline = time.monotonic() + TIMEOUT
    while True:
        path = probe.get_parameters('fault_schedule')['fault_schedule']
        if path == '' or time.monotonic() > deadline:
            return path
        time.sleep(POLL_S)


@pytest.mark.parametrize('kind', list(BAD_SCHEDULES))
def test_a_bad_schedule_set_live_is_refused_and_publishing_goes_on(wall, kind):
    """
    Every kind of bad file: refused (at once, or once checked), and never a freeze.

    The file is checked in a process of its own, so the tick goes on meanwhile;
    fault_schedule is set back to the file in use ('').
    """
    process, probe, folder = wall
    path = folder / f'schedule_{list(BAD_SCHEDULES).index(kind)}.yaml'
    make_file(path, BAD_SCHEDULES[kind])
    start = probe.count()
    result = probe.set_parameters(fault_schedule=str(path))[0]
    assert result.successful or str(path) in result.reason, result.reason
    assert schedule_in_effect(probe) == ''
    probe.wait_for_new_samples(200)
    assert process.poll() is None, 'valve_node died'
    assert largest_stamp_gap(probe, start) < MAX_STAMP_GAP_NS


def test_refused_schedules_are_counted_and_reported(wall):
    """Diagnostics: refused_fault_schedules counts the files refused once read."""
    _, probe, folder = wall
    path = folder / 'refused.yaml'
    make_file(path, YAML_TEXTS['a list alias bomb'])
    before = int(probe.wait_for_diagnostics()['refused_fault_schedules'])
    assert probe.set_parameters(fault_schedule=str(path))[0].successful  # opened, then read
    report = counter(probe, 'refused_fault_schedules', before + 1)
    assert str(path) in report['fault_schedule_refused'] and 'aliases' in report['message']
    assert report['level'] >= 1 and report['fault_schedule'] == ''


def test_a_schedule_is_read_once_what_was_checked_is_applied(wall):
    """
    The file changes between good and bad all the time: each set is in use or refused.

    Read once (the file opened by the check is the one read), never checked in one
    form and applied in another (which killed the node in its post-set callback).
    """
    process, probe, folder = wall
    path, good, bad = folder / 'changing.yaml', folder / 'good.yaml', folder / 'bad.yaml'
    good.write_text('events:\n  - t: 500\n    set: {sensor.supply_pressure.bias: 1000.0}\n')
    bad.write_bytes(os.urandom(1000))
    stop = threading.Event()

    def change():
        while not stop.is_set():
            for source in (good, bad):
                os.link(source, folder / 'next.yaml')
                os.replace(folder / 'next.yaml', path)

    changer = threading.Thread(target=change)
    changer.start()
    try:
        for _ in range(4):
            probe.set_parameters(fault_schedule=str(path))
            report = probe.wait_for_diagnostics(
                lambda values: values['fault_schedule_loading'] == '', 'the file checked'
            )
            assert report['fault_schedule'] in ('', str(path))
            assert report['fault_schedule_events_pending'] in ('0', '1')
            assert probe.set_parameters(fault_schedule='')[0].successful
    finally:
        stop.set()
        changer.join()
    assert process.poll() is None, 'valve_node died'


@pytest.mark.parametrize('content', [None, b'\x89PNG\r\n\x1a\n\x00\x00\xff\xfe binary'])
def test_a_bad_schedule_at_start_is_one_fatal_line(tmp_path, content):
    """A missing or unreadable schedule file given at start: one FATAL line, exit code 1."""
    path = tmp_path / 'schedule.yaml'
    if content is not None:
        path.write_bytes(content)
    log = tmp_path / 'valve_node.log'
    process = start_node(log, '-p', f'fault_schedule:={path}')
    assert process.wait(timeout=TIMEOUT * 5) == 1
    lines = log.read_text().strip().splitlines()
    assert len(lines) == 1 and '[FATAL]' in lines[0] and str(path) in lines[0], lines


@pytest.mark.parametrize('period', ['0.0', '100.0'])
def test_a_diagnostics_period_out_of_its_range_is_one_fatal_line(tmp_path, period):
    """diagnostic_updater.period outside 0.05 ... 60 s at start: one FATAL line, exit code 1."""
    log = tmp_path / 'valve_node.log'
    process = start_node(log, '-p', f'diagnostic_updater.period:={period}')
    assert process.wait(timeout=TIMEOUT * 5) == 1
    lines = log.read_text().strip().splitlines()
    assert len(lines) == 1 and '[FATAL]' in lines[0] and 'diagnostic_updater.period' in lines[0]


def test_a_scheduled_event_refused_after_one_applied_keeps_the_node_running(context, tmp_path):
    """
    A schedule whose first event is applied and whose second is refused (range_min > range_max).

    The refusal is logged at ERROR after an INFO from the same place, which rclpy refuses
    from one call site: the node died there.
    """
    schedule = tmp_path / 'schedule.yaml'
    schedule.write_text(
        'events:\n'
        '  - t: 0.01\n'
        '    set: {fault.damping_orifice_blockage: 0.1}\n'
        '  - t: 0.02\n'
        '    set: {sensor.pilot_pressure.range_max: 1.0e5,\n'
        '          sensor.pilot_pressure.range_min: 2.0e5}\n'
    )
    log = tmp_path / 'valve_node.log'
    with running_valve(
        context, log, '-p', f'fault_schedule:={schedule}', namespace='/hostile_refused'
    ) as (process, probe):
        probe.wait_for(lambda: 'refused' in log.read_text(), 'the refused event logged')
        probe.wait_for_new_samples(100)
        assert process.poll() is None, log.read_text()
    text = log.read_text()
    assert '[INFO]' in text and 'damping_orifice_blockage' in text
    assert '[ERROR]' in text and 'range_max' in text


# --- on /clock ----------------------------------------------------------------------------------


@pytest.fixture(scope='module')
def sim(context, tmp_path_factory):
    """Yield the node on /clock, its clock anchored: (process, probe, log path)."""
    folder = tmp_path_factory.mktemp('hostile_sim')
    log = folder / 'valve_node.log'
    with running_valve(
        context,
        log,
        '--params-file',
        str(config_path('reference.yaml')),
        *FAST_DIAGNOSTICS,
        namespace='/hostile_sim',
        use_sim_time=True,
    ) as (process, probe):
        probe.start_clock(START_S * NS_PER_S, PERIOD_NS)
        yield process, probe, log


def reference_values():
    """Return the declared values a node is restored to: reference parameters, no fault."""
    loaded = load_parameters()
    params, settings = loaded.params, loaded.settings
    return {
        **params,
        **{name: settings[name] for name in ('step_size', 'publish_rate', 'ambient_pressure')},
        'fault.damping_orifice_blockage': 0.0,
        'sensor.supply_pressure.bias': 0.0,
    }


@pytest.fixture
def sim_valve(sim):
    """Yield the node on /clock restored: reference parameters and settings, 5 L/min."""
    process, probe, _ = sim
    probe.restore(reference_values(), FLOW)
    yield probe
    assert process.poll() is None, 'valve_node died'
    assert probe.non_finite == 0, 'a NaN or inf was published'


@pytest.mark.parametrize(
    'sec, nanosec', [(-5, 0), (-1, 999_999_999), (2**31 - 1, 4_000_000_000)]
)
def test_a_clock_the_node_cannot_represent_is_ignored_and_counted(sim_valve, sec, nanosec):
    """Negative seconds, or past 2^31 s: ignored, counted; the node goes on with its clock."""
    stamp_ns, expected_ns = bad_clock_then_good(sim_valve, sec, nanosec)
    assert stamp_ns == expected_ns


def bad_clock_then_good(probe, sec, nanosec):
    """
    Publish /clock (sec, nanosec) until the node counts it refused, then 20 good ticks.

    Returns (the stamp of the last state published, the stamp expected: 20 periods on).
    """
    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock

    before = int(probe.wait_for_diagnostics()['refused_clock_messages'])
    now_ns = probe.clock_ns

    def refused():
        probe.clock.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))  # best effort: again
        return any(int(d['refused_clock_messages']) > before for d in probe.diagnostics[-3:])

    probe.wait_for(refused, 'the bad /clock counted')
    probe.send_clock(now_ns)
    probe.run_until(now_ns + 20 * PERIOD_NS)  # ticking on the good clock as before
    return probe.latest()[0], now_ns + 20 * PERIOD_NS


def change_and_overpressure(probe, **change):
    """
    Apply change with max_inlet_flow lifted, then a flow no valve relieves: an overpressure.

    On /clock the change and the flow reach the node between two ticks, so the failure
    falls inside the roll-back window. Returns the declared values before the change.
    """
    names = [*change, 'max_inlet_flow', 'preset_pressure', 'pilot_spring_preload']
    before = probe.get_parameters(*names)
    result = probe.set_parameters_atomically(**change, max_inlet_flow=LIFTED_MAX_FLOW)
    assert result.successful, result.reason
    overpressure(probe)
    return before


def take_flow(probe, flow):
    """Send flow while the clock is paused; return once the node holds it (its housekeeping)."""
    accepted = int(probe.wait_for_diagnostics()['accepted_inputs'])
    probe.send_flow(flow)
    probe.wait_for_diagnostics(
        lambda values: int(values['accepted_inputs']) > accepted
        and float(values['inlet_flow_m3_s']) == flow,
        f'the flow {flow:g} m^3/s taken',
    )


def tick_exactly(probe, time_ns):
    """
    Publish /clock = time_ns until the state stamped exactly time_ns arrives.

    Probe.tick_at waits for a stamp at or after time_ns: after the clock jumped back,
    the states of before the jump are later.
    """
    rows = probe.pressures['supply_pressure']
    deadline = time.monotonic() + TIMEOUT
    while not probe._wait(lambda: any(stamp == time_ns for stamp, _ in rows[-20:]), 1.0):
        assert time.monotonic() < deadline, f'no state stamped {time_ns} ns'
        probe.send_clock(time_ns)


def overpressure(probe, tick=None):
    """
    Let the node take ABSURD_FLOW while its clock is paused, then tick: it fails in that tick.

    Without ticks the node's housekeeping takes the waiting input, so the flow is
    in use before the next tick, whatever the machine's load.
    """
    take_flow(probe, ABSURD_FLOW)
    (tick or probe.next_tick)()
    return probe.wait_for_diagnostics(
        lambda values: values['halted'] == 'true' and int(values['overpressures']) > 0,
        'the overpressure and the halt',
    )


ROLL_BACK_CASES = {
    'a model parameter': {'main_valve_damping': 20.0},
    'step_size': {'step_size': 5e-6},
    'a fault': {'fault.damping_orifice_blockage': 0.1},
    'a sensor setting': {'sensor.supply_pressure.bias': 1000.0},
    'the preset': {'preset_pressure': 6.5e6},
    'publish_rate': {'publish_rate': 2000.0},
    'ambient_pressure': {'ambient_pressure': 90000.0},
}


@pytest.mark.parametrize('kind', list(ROLL_BACK_CASES))
def test_a_roll_back_restores_everything_it_rolls_back(sim_valve, kind):
    """
    After the roll-back the declared parameters, the model and the diagnostics agree.

    Each kind of parameter is changed together with max_inlet_flow; the overpressure
    that follows at once rolls the whole change back. A later, unrelated change must
    not bring any of it back (the step size did, with the settings not restored).
    """
    probe = sim_valve
    change = ROLL_BACK_CASES[kind]
    steady_readings = {topic: probe.latest(topic)[1] for topic in PRESSURE_TOPICS}
    before = change_and_overpressure(probe, **change)
    report = probe.wait_for_diagnostics()
    assert probe.get_parameters(*before) == before
    assert float(report['step_size_s']) == pytest.approx(load_parameters().settings['step_size'])
    assert float(report['publish_rate_hz']) == load_parameters().settings['publish_rate']
    assert report['faults_active'] == ''
    probe.next_tick()
    # The absurd flow still held halts the restored model at its last good state: p_s
    # reads at burst_pressure (an overpressure on the wire), the other chambers as before.
    loaded = load_parameters()
    params, settings = loaded.params, loaded.settings
    burst = params['burst_pressure'] + settings['ambient_pressure']
    assert probe.latest()[1] == pytest.approx(burst, rel=1e-12)
    for topic in PRESSURE_TOPICS[1:]:
        assert probe.latest(topic)[1] == pytest.approx(steady_readings[topic], rel=1e-6), (
            f'{topic} as before the change'
        )
    take_flow(probe, FLOW)  # the absurd flow held would refuse any change
    probe.next_tick()
    assert probe.set_parameters(input_timeout=30.0)[0].successful  # unrelated
    probe.next_tick()
    assert probe.get_parameters(*before) == before
    report = probe.wait_for_diagnostics(
        lambda values: values['input_timeout_s'] == '30.0', 'the unrelated change'
    )
    assert float(report['step_size_s']) == pytest.approx(load_parameters().settings['step_size'])
    assert report['faults_active'] == '' and report['sensor_dropout'] == ''
    timeout = load_parameters().settings['input_timeout']
    assert probe.set_parameters(input_timeout=timeout)[0].successful


def test_a_clock_jump_back_starts_a_new_time_base_for_the_roll_back_window(sim_valve, sim):
    """
    A preset change, 1000 s of clock, a jump back by 2000 s, then an overpressure.

    The change is 1000 s of model time old: no roll-back (it was, when the time of the
    last change stayed in the old time base); the model halts with the change kept.
    """
    probe = sim_valve
    log = sim[2]
    jumps, report = preset_change_jump_back_overpressure(probe)
    assert int(report['clock_jumps_back']) == jumps + 1
    assert probe.get_parameters('preset_pressure')['preset_pressure'] == pytest.approx(6.5e6)
    assert 'rolled back' not in Path(log).read_text().split('clock jumped back')[-1]
    take_flow(probe, FLOW)  # a flow the next restore's max_inlet_flow accepts


def preset_change_jump_back_overpressure(probe):
    """
    Change the preset, run 1000 s of clock, jump back by 2000 s, then an overpressure.

    Returns (clock_jumps_back before the jump, the diagnostics of the overpressure).
    """
    result = probe.set_parameters_atomically(preset_pressure=6.5e6, max_inlet_flow=LIFTED_MAX_FLOW)
    assert result.successful, result.reason
    start_ns = probe.clock_ns
    probe.tick_at(start_ns + 1000 * NS_PER_S)  # the lag beyond the catch-up limit is skipped
    jumps = int(probe.wait_for_diagnostics()['clock_jumps_back'])
    back_ns = start_ns - 1000 * NS_PER_S
    probe.send_clock(back_ns)
    tick_exactly(probe, back_ns + PERIOD_NS)  # the first tick after the jump: a new time base
    return jumps, overpressure(probe, lambda: tick_exactly(probe, back_ns + 2 * PERIOD_NS))


def test_the_schedule_check_process_answers_in_one_line():
    """`python -m valve_sim.core.fault_schedule FD PATH`, valve_node's checker: one JSON line."""
    result = subprocess.run(
        [sys.executable, '-m', 'valve_sim.core.fault_schedule', '0', '/nonexistent'],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )
    assert result.returncode == 1 and 'error' in result.stdout, result
