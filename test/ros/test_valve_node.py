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
valve_node over real DDS, the node in its own process (issue 3, "done means").

Two nodes serve the module's tests. One runs on simulated time (use_sim_time,
/clock published here in lockstep), for what must not depend on how busy the
machine is: the step response compared with the offline simulation, the reset
from inside a transient, the publish rate. The other runs on the wall clock.
Before each test a fixture restores the test's node to a known state (5 L/min, the
reference parameters and settings, the exact steady state) and waits for samples
stamped after that restore, so the tests hold in any order and alone. No test
asserts wall-clock timing.
"""

import math
import os
from pathlib import Path
import signal
import time

import numpy as np
import pytest
import rclpy
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Float64
from valve_harness import PRESSURE_TOPICS, running_valve, start_node, TIMEOUT
from valve_sim.analysis.steps.measures import MEASURE_NAMES, step_measures
from valve_sim.analysis.steps.step_detection import detect_steps
from valve_sim.core.model import P_S, X
from valve_sim.core.parameters import config_path, load_parameters, SPECS
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, simulate
from valve_sim.core.steady_state import (
    cracking_pressure,
    preload_for_cracking_pressure,
    steady_state,
)
from valve_sim.ros.receive_threads import RECEIVE_THREAD
from valve_sim.ros.valve_node import CATCH_UP_LIMIT_PERIODS


pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures('valve_node_kernels')]

AMBIENT = 101325.0  # [Pa] ambient_pressure default
INITIAL_FLOW = 5.0 * LITRE_PER_MINUTE
FINAL_FLOW = 20.0 * LITRE_PER_MINUTE
PERIOD_NS = 1_000_000  # 1 kHz
WINDOW_NS = 1_000_000_000  # measures need 1 s after the step
SIM_NAMESPACE = '/sim'  # the simulated-time node; the wall-clock one runs in /
RETUNABLE_SETTINGS = ('step_size', 'publish_rate', 'input_timeout', 'ambient_pressure')


@pytest.fixture(scope='module')
def reference_settings():
    return load_parameters().settings


@pytest.fixture(scope='module')
def valve_log(tmp_path_factory):
    """Return the path of the wall-clock node's log."""
    return tmp_path_factory.mktemp('valve_node') / 'valve_node.log'


@pytest.fixture(scope='module')
def valve_process(context, valve_log):
    """
    Run the wall-clock node with a connected probe; yield (process, probe).

    Its overrides set the retired swept_inner_diameter, as an older calibrated.yaml does.
    """
    with running_valve(context, valve_log, '-p', 'swept_inner_diameter:=0.0208') as running:
        yield running


@pytest.fixture(scope='module')
def defaults(reference, reference_settings):
    """Return the parameters and retunable settings every test starts from."""
    return {**reference, **{name: reference_settings[name] for name in RETUNABLE_SETTINGS}}


@pytest.fixture
def valve(valve_process, defaults):
    """
    Yield the probe of the wall-clock node, restored to a known state first.

    The known state: the reference parameters and settings, 5 L/min applied, the
    exact steady state, and the probe's samples from after that reset (asserted
    by Probe.restore). So no test sees what an earlier one left behind.
    """
    process, probe = valve_process
    assert process.poll() is None, 'valve_node died'
    probe.restore_ns = probe.restore(defaults, INITIAL_FLOW)
    yield probe
    assert process.poll() is None, 'valve_node died'
    assert probe.non_finite == 0, 'a NaN or inf was published'


def supply_gauge(probe):
    """Latest supply pressure [Pa, gauge]."""
    return probe.latest()[1] - AMBIENT


def after_reset(probe):
    """Reset and return the first supply pressure [Pa, gauge] published afterwards."""
    return probe.first_after(probe.reset())[1] - AMBIENT


# --- on simulated time: the paper's step, compared with the offline simulation -----------------


@pytest.fixture(scope='module')
def sim_process(context, tmp_path_factory):
    """
    Run a node on /clock (use_sim_time) in its own namespace; the probe has anchored its clock.

    The node starts from the reference parameter file plus a file with an integer for a
    double parameter (lenient typing).
    """
    directory = tmp_path_factory.mktemp('sim_valve')
    integers = directory / 'integers.yaml'
    integers.write_text('relief_valve:\n  ros__parameters:\n    main_valve_damping: 0\n')
    with running_valve(
        context,
        directory / 'valve_node.log',
        '--params-file',
        str(config_path('reference.yaml')),
        '--params-file',
        str(integers),
        namespace=SIM_NAMESPACE,
        use_sim_time=True,
        stop_signal=signal.SIGTERM,
    ) as (process, probe):
        probe.start_clock(100 * 1_000_000_000, PERIOD_NS)
        yield process, probe


@pytest.fixture
def sim_valve(sim_process, defaults):
    """
    Yield the probe of the simulated-time node, restored to a known state first.

    As valve(), with the probe ticking the node: restore_ns is the reset's model
    time, and exactly one state (stamped a period later) has been published since.
    """
    process, probe = sim_process
    probe.restore_ns = probe.restore(defaults, INITIAL_FLOW)
    yield probe
    assert process.poll() is None, 'valve_node died'
    assert probe.non_finite == 0, 'a NaN or inf was published'


def test_step_response_matches_offline_simulation(sim_valve, reference):
    """5 -> 20 L/min on inlet_flow: the six measures agree with `valve-sim simulate`."""
    probe = sim_valve
    probe.run_until(probe.restore_ns + 50 * PERIOD_NS)
    step_to(probe, FINAL_FLOW)
    probe.run_until(probe.clock_ns + WINDOW_NS + 5 * PERIOD_NS)

    t, p_s, x, t_step = node_waveforms(probe, probe.restore_ns)
    node = step_measures(t, p_s, x, t_step)
    offline_run = simulate(
        reference,
        FlowStep(INITIAL_FLOW, FINAL_FLOW, step_time=t_step, end_time=t_step + 1.01),
        step_size=1e-5,
        record_interval=1e-4,
    )
    offline = step_measures(
        offline_run.time,
        offline_run['supply_pressure'],
        offline_run['main_valve_displacement'],
        t_step,
    )
    for name in MEASURE_NAMES:
        assert node.values[name] is not None, f'{name}: {node.reasons.get(name)}'
        if name == 'T_1_ms':
            assert node.values[name] == pytest.approx(offline.values[name], abs=0.2), name
        else:
            assert node.values[name] == pytest.approx(offline.values[name], rel=0.02), name


def test_publish_rate_change_recreates_the_timer(sim_valve):
    """At 200 Hz the valve ticks only every 5 ms of clock time, however often /clock moves."""
    probe = sim_valve
    assert probe.set_parameters(publish_rate=200.0)[0].successful
    changed_ns = probe.clock_ns
    for tick in range(1, 5):
        for millisecond in range(1, 5):
            probe.send_clock(changed_ns + (5 * (tick - 1) + millisecond) * PERIOD_NS)
            time.sleep(0.05)  # gives a 1 kHz timer, if there were one, the chance to tick
        probe.tick_at(changed_ns + 5 * tick * PERIOD_NS)
    with probe.condition:
        stamps = [s for s, _ in probe.pressures['supply_pressure'] if s > changed_ns]
    assert stamps == [changed_ns + 5 * tick * PERIOD_NS for tick in range(1, 5)]


def test_reset_returns_to_the_steady_state_of_the_current_flow(sim_valve, reference):
    """A reset 20 ms into the 20 L/min transient: the next state is that flow's steady state."""
    probe = sim_valve
    step_to(probe, FINAL_FLOW)
    probe.run_until(probe.clock_ns + 20 * PERIOD_NS)
    expected = steady_state(reference, FINAL_FLOW)
    assert supply_gauge(probe) != pytest.approx(expected[P_S], rel=1e-3), 'in the transient'
    reset_ns = probe.reset()
    probe.next_tick()
    assert probe.first_after(reset_ns)[1] - AMBIENT == pytest.approx(expected[P_S], rel=1e-6)
    x_after = probe.first_after(reset_ns, 'joint_states')[1]
    assert x_after == pytest.approx(expected[X], rel=1e-4)


def test_diagnostics_go_on_while_the_clock_is_paused(sim_valve):
    """
    Housekeeping follows a tick; with /clock paused (no ticks) the 1 Hz report still comes.

    The first report awaited is one of the paused clock's (a report of the tick before
    may still be on its way); the next must come, a second later, with nothing moved.
    """
    paused = repr(sim_valve.clock_ns / 1e9)
    first = sim_valve.wait_for_diagnostics(
        lambda d: d['model_time_s'] == paused, 'a report at the paused model time'
    )
    second = sim_valve.wait_for_diagnostics()
    assert second['model_time_s'] == paused
    assert int(second['ticks']) == int(first['ticks'])


def step_to(probe, flow):
    """Send flow [m^3/s] to the simulated-time node; tick until a state has applied it."""
    probe.send_flow(flow)
    while probe.applied[-1][1] != flow:
        probe.next_tick()


def node_waveforms(probe, start_ns):
    """
    Return (t [s], p_s [Pa gauge], x [m], t_step [s]) of the states published after start_ns.

    t counts from start_ns [ns].
    """
    with probe.condition:
        pressure = {s: p for s, p in probe.pressures['supply_pressure'] if s > start_ns}
        displacement = {row[0]: row[1] for row in probe.joints if row[0] > start_ns}
        applied = [row for row in probe.applied if row[0] > start_ns]
    stamps = np.array(sorted(pressure.keys() & displacement.keys()))
    assert np.all(np.diff(stamps) == PERIOD_NS), 'lockstep samples are 1 ms apart'
    t = (stamps - start_ns) / 1e9
    p_s = np.array([pressure[s] for s in stamps]) - AMBIENT
    x = np.array([displacement[s] for s in stamps])
    ((t_step, flow_before, direction),) = detect_steps(
        [(row[0] - start_ns) / 1e9 for row in applied], [row[1] for row in applied]
    )
    assert (flow_before, direction) == (INITIAL_FLOW, 1)
    return t, p_s, x, t_step


# --- the shared wall-clock node --------------------------------------------------------------


def test_publishes_each_tick_with_one_stamp_at_the_steady_state(valve, reference, defaults):
    expected = steady_state(reference, INITIAL_FLOW)
    valve.wait_for_new_samples(20, 'poppet_chamber_pressure')
    with valve.condition:
        stamps = [
            {s: p for s, p in rows if s > valve.restore_ns} for rows in valve.pressures.values()
        ]
        joints = {row[0]: row[1:] for row in valve.joints if row[0] > valve.restore_ns}
        applied = {s: q for s, q in valve.applied if s > valve.restore_ns}
    common = sorted(set.intersection(*(set(rows) for rows in stamps), joints, applied))
    assert len(common) >= 10, 'messages of a tick share one stamp'
    stamp = common[-1]
    for index, rows in enumerate(stamps):
        assert rows[stamp] - AMBIENT == pytest.approx(expected[index], rel=1e-6), PRESSURE_TOPICS[
            index
        ]
    assert joints[stamp][0] == pytest.approx(expected[X], rel=1e-6)
    assert applied[stamp] == INITIAL_FLOW
    # Model time moves in whole steps; only lag beyond the catch-up limit is skipped
    # (a jump of more than CATCH_UP_LIMIT_PERIODS periods, not a whole number of steps).
    step_ns = round(defaults['step_size'] * 1e9)
    catch_up_ns = CATCH_UP_LIMIT_PERIODS * PERIOD_NS
    assert all((b - a) % step_ns == 0 for a, b in zip(common, common[1:]) if b - a <= catch_up_ns)


def test_parameter_descriptors_carry_unit_and_range(valve):
    future = valve.parameters.describe_parameters(
        ['main_valve_mass', 'preset_pressure', 'step_size']
    )
    descriptors = valve._result(future).descriptors
    mass, preset, step = descriptors
    assert '[kg]' in mass.description and 'Table 1' in mass.description
    assert (mass.floating_point_range[0].from_value, mass.floating_point_range[0].to_value) == (
        SPECS['main_valve_mass'].minimum,
        SPECS['main_valve_mass'].maximum,
    )
    assert '[Pa]' in preset.description and '[s]' in step.description


def test_live_parameter_change_takes_effect(valve, reference):
    preload = reference['pilot_spring_preload'] * 1.05
    before = supply_gauge(valve)
    assert all(result.successful for result in valve.set_parameters(pilot_spring_preload=preload))
    changed = {**reference, 'pilot_spring_preload': preload}
    reported = valve.get_parameters('pilot_spring_preload', 'preset_pressure')
    assert reported['pilot_spring_preload'] == preload
    assert reported['preset_pressure'] == pytest.approx(cracking_pressure(changed), rel=1e-9)
    valve.wait_for(
        lambda: valve.latest()[1] - AMBIENT > before + 1e4,
        'supply pressure rising with the preload',
    )
    assert after_reset(valve) == pytest.approx(steady_state(changed, INITIAL_FLOW)[P_S], rel=1e-6)


def test_integer_is_accepted_for_a_double_parameter(valve):
    assert valve.set_parameters(main_valve_damping=2)[0].successful
    assert valve.get_parameters('main_valve_damping') == {'main_valve_damping': 2.0}


def invalid_changes(reference):
    """(change, words its refusal must contain): each kind of invalid change once."""
    return [
        ({'main_valve_mass': math.nan}, ('main_valve_mass', 'finite')),
        ({'main_valve_mass': -0.065}, ('main_valve_mass', 'limits [0.0001, 10] kg')),
        (
            {'first_throttle_inner_diameter': reference['first_throttle_outer_diameter']},
            ('first_throttle_outer_diameter', 'must exceed'),
        ),
        ({'main_valve_mass': 'heavy'}, ('main_valve_mass', 'must be a number in kg', 'string')),
        # a 0.1 g main valve on a 1 mm^3 pilot chamber of stiff water at 100 us: it rings
        # beyond the sub-steps allowed (a stiff chamber alone integrates: ROS2)
        ({'main_valve_mass': 1e-4, 'main_valve_damping': 1e4, 'pilot_volume': 1e-9,
          'bulk_modulus': 1e10, 'step_size': 1e-4}, ('cannot be integrated', 'ring')),
        ({'preset_pressure': 1e5}, ('pilot_spring_preload', 'limits')),
        ({'initial_inlet_flow': 0.0}, ('read-only', 'initial_inlet_flow')),
    ]


def test_invalid_parameter_changes_are_rejected_with_their_reason(valve, reference):
    changes = invalid_changes(reference)
    names = sorted({name for change, _ in changes for name in change})
    before = valve.get_parameters(*names)
    refused_before = int(valve.wait_for_diagnostics()['rejected_parameter_changes'])
    for change, words in changes:
        (result,) = (valve.set_parameters(**change) if len(change) == 1
                     else [valve.set_parameters_atomically(**change)])
        assert not result.successful, change
        for word in words:
            assert word in result.reason, (change, result.reason)
    assert valve.get_parameters(*names) == before
    valve.wait_for_new_samples(10)
    assert supply_gauge(valve) == pytest.approx(
        steady_state(reference, INITIAL_FLOW)[P_S], rel=1e-6
    )
    valve.wait_for_diagnostics(
        lambda d: int(d['rejected_parameter_changes']) >= refused_before + len(changes),
        'rejected_parameter_changes counted',
    )


def test_an_undeclared_name_is_refused_with_the_declared_name_meant(valve):
    (symbol,) = valve.set_parameters(m_m=0.07)
    assert not symbol.successful
    assert "'m_m'" in symbol.reason and "'main_valve_mass'" in symbol.reason, symbol.reason
    (typo,) = valve.set_parameters(main_valve_mas=0.07)
    assert not typo.successful and "did you mean 'main_valve_mass'" in typo.reason, typo.reason


def test_the_retired_swept_inner_diameter_is_ignored_with_a_warning_and_refused_live(
    valve, valve_log
):
    log = valve_log.read_text()
    assert 'ignoring swept_inner_diameter (a parameter file or -p sets it)' in log
    assert 'A_m1 of Eq. (1) is now the supply force area alpha_s' in log
    (result,) = valve.set_parameters(swept_inner_diameter=0.0208)
    assert not result.successful and 'no longer exists' in result.reason, result.reason


def test_inconsistent_geometry_set_atomically_is_rejected_as_a_whole(valve, reference):
    mass = reference['main_valve_mass'] * 1.1
    result = valve.set_parameters_atomically(
        first_throttle_outer_diameter=reference['first_throttle_inner_diameter'] * 0.99,
        main_valve_mass=mass,
    )
    assert not result.successful and 'first_throttle_outer_diameter' in result.reason
    assert valve.get_parameters('main_valve_mass')['main_valve_mass'] != mass


def test_a_best_effort_inlet_flow_publisher_is_heard(context, valve):
    """
    A bench publishing with SensorDataQoS (best effort) drives the valve too.

    The publisher is on a node of its own: the probe's node is not changed while its
    executor spins it in another thread.
    """
    bench = rclpy.create_node('best_effort_bench', context=context)
    publisher = bench.create_publisher(Float64, 'inlet_flow', qos_profile_sensor_data)
    try:
        valve.wait_for(
            lambda: publisher.get_subscription_count() > 0, 'valve_node matching a best-effort one'
        )
        deadline = time.monotonic() + TIMEOUT
        while not valve._wait(lambda: valve.applied[-1][1] == FINAL_FLOW, 0.05):
            assert time.monotonic() < deadline, 'the best-effort flow was never applied'
            publisher.publish(Float64(data=FINAL_FLOW))  # periodically, as a bench does
    finally:
        bench.destroy_node()


def test_flood_of_bad_inlet_flows_is_rejected_and_never_reaches_an_output(valve_process, valve):
    process, _ = valve_process
    rejected_before = int(valve.wait_for_diagnostics()['rejected_inputs'])
    with valve.condition:
        applied_before = len(valve.applied)
    for _ in range(100):
        for bad in (math.nan, math.inf, -math.inf, -1e-4):
            valve.send_flow(bad)
    valve.wait_for_new_samples(200)
    assert process.poll() is None
    assert valve.non_finite == 0
    with valve.condition:
        assert all(q == INITIAL_FLOW for _, q in valve.applied[applied_before:]), (
            'last good flow held'
        )
    diagnostics = valve.wait_for_diagnostics(
        lambda d: int(d['rejected_inputs']) > rejected_before, 'rejected_inputs counted'
    )
    assert int(diagnostics['rejected_inputs']) - rejected_before <= 400


def test_preset_pressure_moves_the_cracking_point(valve, reference):
    cracking = cracking_pressure(reference)
    assert valve.get_parameters('preset_pressure')['preset_pressure'] == pytest.approx(
        cracking, rel=1e-9
    )
    before = supply_gauge(valve)
    preset = cracking + 0.5e6
    assert valve.set_parameters(preset_pressure=preset)[0].successful
    preload = valve.get_parameters('pilot_spring_preload')['pilot_spring_preload']
    assert preload == pytest.approx(preload_for_cracking_pressure(reference, preset), rel=1e-9)
    moved = {**reference, 'pilot_spring_preload': preload}
    assert cracking_pressure(moved) == pytest.approx(preset, rel=1e-6)
    assert after_reset(valve) - before == pytest.approx(0.5e6, rel=0.05)
    conflicting = valve.set_parameters_atomically(
        preset_pressure=preset + 1e5, pilot_spring_preload=preload
    )
    assert not conflicting.successful and 'disagrees' in conflicting.reason


def test_diagnostics_report_health_and_stale_input(valve):
    assert valve.set_parameters(input_timeout=0.2)[0].successful
    # A node's first report has no real-time factor (no window of ticks before it yet).
    stale = valve.wait_for_diagnostics(
        lambda d: d['input_stale'] == 'true' and d['real_time_factor'] != '',
        'input reported stale',
    )
    assert stale['level'] >= 1 and 'stale' in stale['message']
    for key in (
        'real_time_factor',
        'ticks',
        'late_ticks',
        'long_ticks',
        'missed_ticks',
        'skipped_ticks',
        'skipped_time_s',
        'rejected_inputs',
        'rejected_parameter_changes',
        'integration_failures',
        'tick_compute_p50_ms',
        'tick_compute_p99_ms',
        'inlet_flow_m3_s',
        'model_time_s',
        'startup_kernels_s',
    ):
        assert key in stale, key
    assert float(stale['inlet_flow_m3_s']) == INITIAL_FLOW
    assert float(stale['real_time_factor']) > 0.0
    assert float(stale['startup_kernels_s']) > 0.0
    with valve.condition:
        start = len(valve.diagnostics)

    def fresh():
        return any(d['input_stale'] == 'false' for d in valve.diagnostics[start:])

    deadline = time.monotonic() + TIMEOUT
    # an input every 50 ms, within the 0.2 s timeout, until a report shows it fresh
    while not valve._wait(fresh, 0.05):
        assert time.monotonic() < deadline, 'input never reported fresh again'
        valve.send_flow(INITIAL_FLOW)


# --- the receive threads ----------------------------------------------------------------------


def receive_thread_policies(pid):
    """Return {name: scheduling policy} of the middleware receive threads of process pid."""
    policies = {}
    for task in Path(f'/proc/{pid}/task').iterdir():
        name = (task / 'comm').read_text().strip()
        if RECEIVE_THREAD.match(name):
            policies[name] = os.sched_getscheduler(int(task.name))
    return policies


def test_a_stalled_node_counts_the_slots_it_slept_through(valve_process, valve):
    """SIGSTOP for 0.3 s: the next tick is late, 0.3 s of slots missed, the lag skipped."""
    process, _ = valve_process
    report = valve.wait_for_diagnostics()
    before = {key: float(report[key]) for key in ('late_ticks', 'missed_ticks', 'skipped_time_s')}
    process.send_signal(signal.SIGSTOP)
    try:
        time.sleep(0.3)  # the stall itself (at least this long), not a wait for a condition
    finally:
        process.send_signal(signal.SIGCONT)
    after = valve.wait_for_diagnostics(
        lambda d: float(d['missed_ticks']) >= before['missed_ticks'] + 250, 'the stall counted'
    )
    assert float(after['late_ticks']) > before['late_ticks']
    # the catch-up limit is 50 periods: at least 0.3 s - 50 ms of the lag is skipped
    assert float(after['skipped_time_s']) >= before['skipped_time_s'] + 0.2


def test_receive_threads_idle_run_them_behind_the_tick(context, tmp_path):
    log = tmp_path / 'valve_node.log'
    with running_valve(
        context, log, namespace='/idle', options=('--receive-threads', 'idle')
    ) as (process, probe):
        reported = probe.wait_for_diagnostics()['receive_threads']
        policies = receive_thread_policies(process.pid)
        assert os.sched_getscheduler(process.pid) == os.SCHED_OTHER  # the main thread ticks
    assert policies and set(policies.values()) == {os.SCHED_IDLE}, policies
    assert reported.startswith('SCHED_IDLE: ')
    assert set(reported.removeprefix('SCHED_IDLE: ').split(', ')) == set(policies)


def test_receive_threads_are_left_as_started_by_default(valve_process, valve):
    process, _ = valve_process
    assert valve.wait_for_diagnostics()['receive_threads'].startswith('normal')
    policies = receive_thread_policies(process.pid)
    assert policies and set(policies.values()) == {os.SCHED_OTHER}, policies


# --- the executor option ----------------------------------------------------------------------


def test_runs_on_the_single_threaded_executor_too(context, tmp_path):
    log = tmp_path / 'valve_node.log'
    with running_valve(
        context, log, namespace='/single', options=('--executor', 'single-threaded')
    ) as (_, probe):
        probe.wait_for_new_samples(100)
        assert probe.wait_for_diagnostics()['integration_failures'] == '0'
    assert 'executor: single-threaded' in log.read_text()


def test_an_unknown_executor_is_a_usage_error(tmp_path):
    log = tmp_path / 'valve_node.log'
    process = start_node(log, options=('--executor', 'multi'))
    assert process.wait(timeout=60) == 2
    assert "invalid choice: 'multi'" in log.read_text()
