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
User journeys (issue 24): each feature fed with another feature's output, end to end.

- a rig valve recorded by analyser_node under a namespace -> `analyse --namespace` ->
  `calibrate` -> the calibrated file used by valve_node under the same namespace, whose
  steady state and step measures equal the calibrated offline simulation (lockstep on
  /clock);
- a foreign rig bag (gauge std_msgs/Float64, a flowmeter slower than the pressure) ->
  analyse -> calibrate recovers the valve it was made from;
- a truncated recording -> `repair` -> analyse: the measures its short window cannot
  give are null, with their reason;
- an overpressure on the node: the wire saturated at the limit, a reset, the steady state
  again;
- a tolerance study on the local Dask cluster: nothing of it listens beyond loopback.

Each asserts on results, not on exit codes alone. The valves are made from
config/reference.yaml inside the tests (scaled), so no reference number is written here.
"""

import json
import signal
import subprocess
import sys
import time

import numpy as np
import psutil
import pytest
from std_srvs.srv import Trigger
from test_calibrate import valve_sim
from valve_harness import Recorder, running_valve, TIMEOUT
from valve_sim.analysis.steps.measures import MEASURE_NAMES, step_measures
from valve_sim.analysis.steps.step_detection import detect_steps
from valve_sim.core.model import P_S
from valve_sim.core.parameters import load_parameters, scaled, STANDARD_ATMOSPHERE
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, simulate
from valve_sim.core.steady_state import steady_state


pytestmark = [pytest.mark.timeout(600)]

PERIOD_NS = 1_000_000  # lockstep: one tick a millisecond of /clock
START_NS = 1_795_953_600_000_000_000  # 2026-11-29T12:00:00Z: a rig logger's epoch stamps
INITIAL_FLOW = 5.0 * LITRE_PER_MINUTE
FINAL_FLOW = 20.0 * LITRE_PER_MINUTE
NAMESPACE = '/rig1'


def step_to(probe, flow):
    """Send flow [m^3/s] to a node on /clock; tick until a state has applied it."""
    probe.send_flow(flow)
    while probe.applied[-1][1] != flow:
        probe.next_tick()


def lockstep_step(probe, settle_ticks=50, window_ticks=1100):
    """
    Drive a node on /clock through the paper's step: 5 L/min, then 20 L/min.

    Returns (t [s from the first state], p_s [Pa gauge], x [m], t_step [s]) of the
    published states, t_step the last state with the old flow.
    """
    start_ns = probe.start_clock(100 * 1_000_000_000, PERIOD_NS)
    probe.run_until(start_ns + settle_ticks * PERIOD_NS)
    step_to(probe, FINAL_FLOW)
    probe.run_until(probe.clock_ns + window_ticks * PERIOD_NS)
    with probe.condition:
        pressure = dict(probe.pressures['supply_pressure'])
        position = {row[0]: row[1] for row in probe.joints}
        applied = list(probe.applied)
    stamps = np.array(sorted(pressure.keys() & position.keys()))
    assert np.all(np.diff(stamps) == PERIOD_NS), 'lockstep: a state every millisecond'
    ((t_step, flow_before, _),) = detect_steps(
        [(s - start_ns) / 1e9 for s, _ in applied], [q for _, q in applied]
    )
    assert flow_before == INITIAL_FLOW
    return (
        (stamps - start_ns) / 1e9,
        np.array([pressure[s] for s in stamps]) - STANDARD_ATMOSPHERE,
        np.array([position[s] for s in stamps]),
        t_step,
    )


def recording_everything(probe, namespace, topics):
    """Tick the node until the analyser's status shows messages of every topic recorded."""
    from diagnostic_msgs.msg import DiagnosticArray

    counts = {}

    def on_status(message):
        for status in message.status:
            for pair in status.values:
                if pair.key.startswith('messages '):
                    counts[pair.key[len('messages '):]] = int(pair.value)

    subscription = probe.node.create_subscription(DiagnosticArray, '/diagnostics', on_status, 10)
    deadline = time.monotonic() + TIMEOUT
    while not all(counts.get(f'{namespace}/{topic}', 0) > 0 for topic in topics):
        assert time.monotonic() < deadline, f'the analyser never recorded all of {topics}'
        probe.run_until(probe.clock_ns + 20 * PERIOD_NS)
    probe.node.destroy_subscription(subscription)


@pytest.mark.usefixtures('valve_node_kernels')
def test_record_analyse_calibrate_and_run_the_calibrated_valve_in_a_namespace(
    context, reference, tmp_path
):
    rig = scaled(reference, {'d_c': 6.0})  # the valve on the rig: its damping orifice +6 %
    # A section for the root namespace only: rcl ignores it in /rig1, valve_node says so.
    root_only = tmp_path / 'root_only.yaml'
    root_only.write_text('relief_valve:\n  ros__parameters:\n    preset_pressure: 6.5e6\n')
    recorder = Recorder(tmp_path, NAMESPACE)
    try:
        with running_valve(
            context, tmp_path / 'rig.log', '--params-file', str(root_only), '-p',
            f'damping_orifice_diameter:={rig["damping_orifice_diameter"]!r}',
            namespace=NAMESPACE, use_sim_time=True, stop_signal=signal.SIGTERM,
        ) as (_, probe):
            probe.start_clock(100 * 1_000_000_000, PERIOD_NS)
            recording_everything(
                probe, NAMESPACE, ('supply_pressure', 'joint_states', 'applied_inlet_flow')
            )
            probe.run_until(probe.clock_ns + 50 * PERIOD_NS)
            step_to(probe, FINAL_FLOW)
            probe.run_until(probe.clock_ns + 1100 * PERIOD_NS)
    finally:
        log = recorder.stop(signal.SIGINT)
    assert recorder.process.returncode == 0, log
    rig_log = (tmp_path / 'rig.log').read_text()
    assert f'parameter file {root_only}: no section applies to /rig1/relief_valve' in rig_log
    assert "'/relief_valve' (" in rig_log and 'do not apply to /rig1/relief_valve' in rig_log
    bag = next(tmp_path.glob('valve_*.mcap'))
    (live,) = json.loads(bag.with_suffix('.measures.json').read_text())['steps']

    # analyse --namespace: the live analyser's measures, every one of them
    analysed = valve_sim('analyse', bag, '--namespace', NAMESPACE, '--json')
    (step,) = json.loads(analysed.stdout)['steps']
    for name in MEASURE_NAMES:
        assert step[name] is not None, step['reasons']
        assert step[name] == pytest.approx(live[name], rel=1e-9), name
    detected = valve_sim('analyse', bag, '--json')  # the one namespace, found by itself
    assert json.loads(detected.stdout)['steps'] == [step]
    assert f'under {NAMESPACE}' in detected.stderr

    # calibrate finds the rig's orifice from the recording, writes the file for any namespace
    out = tmp_path / 'calib'
    valve_sim('calibrate', '--bag', bag, '--namespace', NAMESPACE, '--fit', 'd_c', '--starts',
              '1', '--quiet', '--out', out)
    report = json.loads((out / 'report.json').read_text())
    (fitted,) = report['fitted']
    assert fitted['value'] == pytest.approx(rig['damping_orifice_diameter'], rel=1e-4)
    assert '/**/relief_valve:' in (out / 'calibrated.yaml').read_text()
    calibrated = load_parameters(out / 'calibrated.yaml').params

    # valve_node under the same namespace with the calibrated file: the offline model
    with running_valve(
        context, tmp_path / 'calibrated.log', '--params-file', str(out / 'calibrated.yaml'),
        namespace=NAMESPACE, use_sim_time=True, stop_signal=signal.SIGTERM,
    ) as (_, probe):
        t, p_s, x, t_step = lockstep_step(probe)
    node_log = (tmp_path / 'calibrated.log').read_text()
    assert 'applied section(s) /**/relief_valve to /rig1/relief_valve' in node_log
    assert p_s[0] == pytest.approx(steady_state(calibrated, INITIAL_FLOW)[P_S], rel=1e-6)
    live = step_measures(t, p_s, x, t_step)
    run = simulate(calibrated, FlowStep(INITIAL_FLOW, FINAL_FLOW, t_step, t[-1]),
                   record_interval=PERIOD_NS / 1e9)
    offline = step_measures(run.time, run['supply_pressure'], run['main_valve_displacement'],
                            t_step)
    for name in MEASURE_NAMES:
        assert live.values[name] is not None, live.reasons
        assert live.values[name] == pytest.approx(offline.values[name], rel=1e-6), name


@pytest.mark.parametrize('flow_hz', [100, 250])
def test_a_rig_bag_with_a_slow_flowmeter_is_analysed_and_calibrated(reference, tmp_path,
                                                                    flow_hz):
    """
    Gauge Float64 topics, p_s at 1 kHz, the flowmeter at 100 or 250 Hz.

    The step lies between two flow samples and between two pressure samples (0.2537 s).
    """
    rig = scaled(reference, {'d_c': 6.0, 'k_p': -7.0})
    run = simulate(rig, FlowStep(INITIAL_FLOW, FINAL_FLOW, 0.2537, 1.3), record_interval=1e-4)
    truth = step_measures(run.time, run['supply_pressure'], run['main_valve_displacement'],
                          0.2537).values
    topics = ('--topic-supply-pressure', '/rig/p', '--topic-inlet-flow', '/rig/q',
              '--clock', 'receive', '--ambient-pressure', '0')

    def rig_bag(path, noise):
        """p_s [Pa gauge] every 1 ms (noise [Pa]), the flow every 1/flow_hz s, as a logger."""
        from std_msgs.msg import Float64
        from valve_sim.recording.bag import BagWriter

        pressure_every, flow_every = 10, round(1e4 / flow_hz)  # in the run's 0.1 ms samples
        noisy = run['supply_pressure'] + np.random.default_rng(3).normal(0, noise, len(run.time))
        bag = BagWriter(path)
        bag.add_topic('/rig/p', 'std_msgs/msg/Float64')
        bag.add_topic('/rig/q', 'std_msgs/msg/Float64')
        for k in range(0, len(run.time), pressure_every):
            time_ns = START_NS + k * 100_000
            bag.write_message('/rig/p', Float64(data=float(noisy[k])), time_ns, time_ns)
            if k % flow_every == 0:
                flow = Float64(data=float(run.inlet_flow[k]))
                bag.write_message('/rig/q', flow, time_ns, time_ns)
        bag.close()

    # analyse: the step located between the flow samples, the measures of the model's run
    clean = tmp_path / 'clean.mcap'
    rig_bag(clean, 0.0)
    result = valve_sim('analyse', clean, *topics, '--json')
    (step,) = json.loads(result.stdout)['steps']
    assert step['t_step'] - START_NS / 1e9 == pytest.approx(0.2537, abs=0.1e-3)
    for name in ('P_o_percent', 'P_1_percent', 'r_d', 'T_d_ms'):
        assert step[name] == pytest.approx(truth[name], rel=0.01), name
    assert step['T_1_ms'] == pytest.approx(truth['T_1_ms'], abs=0.1)
    first, last = step['details']['t_step_bracket']
    assert last - first == pytest.approx(1.0 / flow_hz, abs=1e-6)  # epoch seconds: 0.24 us
    assert step['details']['t_step_from'] == 'supply_pressure'
    assert step['details']['t_step_uncertainty_s'] <= 0.5e-3 + 1e-6  # half a pressure interval
    assert first < step['t_step'] < last
    text = valve_sim('analyse', clean, *topics).stdout
    assert 'located from the supply pressure' in text and 'uncertainty' in text

    # calibrate on the noisy bag: both parameters within 5 %, inside their 95 % intervals
    noisy = tmp_path / 'noisy.mcap'
    rig_bag(noisy, 1000.0)
    out = tmp_path / 'calib'
    valve_sim('calibrate', '--bag', noisy, *topics, '--fit', 'd_c,k_p', '--quiet', '--out', out)
    report = json.loads((out / 'report.json').read_text())
    true = {**rig, 'step_time_1': 0.2537}  # the step time is fitted too, inside its bracket
    assert [entry['name'] for entry in report['fitted']] == [
        'damping_orifice_diameter', 'pilot_spring_stiffness', 'step_time_1']
    for entry in report['fitted']:
        assert entry['value'] == pytest.approx(true[entry['name']], rel=0.05), entry
        low, high = entry['interval_95']
        assert low <= true[entry['name']] <= high, entry
    assert report['recording']['steps_at_s'] == [report['fitted'][2]['value']]


def test_a_truncated_recording_is_repaired_and_its_short_window_gives_no_final_value(
    tmp_path,
):
    bag = tmp_path / 'step.mcap'
    valve_sim('simulate', '--mcap', bag, '--start-time', '2026-11-29T12:00:00Z')
    data = bag.read_bytes()
    # cut the file so that some 0.1-0.5 s of the window are left, as a killed recorder would
    for fraction in np.linspace(0.25, 0.5, 11):
        cut = tmp_path / f'cut_{fraction:.3f}.mcap'
        cut.write_bytes(data[: int(len(data) * fraction)])
        fixed = tmp_path / f'fixed_{fraction:.3f}.mcap'
        valve_sim('repair', cut, '-o', fixed)
        steps = json.loads(valve_sim('analyse', fixed, '--json').stdout)['steps']
        if steps and 0.1 <= steps[0]['details']['window_s'] <= 0.5:
            break
    else:
        pytest.fail('no cut left a window of 0.1-0.5 s')
    (step,) = steps
    assert 'truncated' in step['details']['note']
    for name in ('P_o_percent', 'P_1_percent', 'r_d', 'T_s_ms'):
        assert step[name] is None and 'has not settled' in step['reasons'][name], name
    assert step['details']['final_value_settled'] is False
    assert step['T_1_ms'] is not None and step['T_d_ms'] is not None  # peaks: inside it
    text = valve_sim('analyse', fixed).stdout
    assert 'P_o_percent: the window is truncated' in text


@pytest.mark.usefixtures('valve_node_kernels')
def test_an_overpressure_saturates_the_wire_and_a_reset_brings_the_steady_state_back(
    context, reference, tmp_path
):
    burst = reference['burst_pressure']
    with running_valve(
        context, tmp_path / 'valve_node.log', '-p', 'max_inlet_flow:=10.0',
        namespace='/overpressure', use_sim_time=True, stop_signal=signal.SIGTERM,
    ) as (_, probe):
        probe.start_clock(100 * 1_000_000_000, PERIOD_NS)
        probe.run_until(probe.clock_ns + 20 * PERIOD_NS)
        probe.send_flow(1.0)  # 60,000 L/min into a 20 L/min valve
        deadline = time.monotonic() + TIMEOUT
        while probe.latest()[1] != burst + STANDARD_ATMOSPHERE:
            assert time.monotonic() < deadline, 'p_s never published at burst_pressure'
            probe.next_tick()
        tripped_ns = probe.latest()[0]
        probe.run_until(probe.clock_ns + 30 * PERIOD_NS)
        with probe.condition:
            held = {topic: {p for s, p in rows if s >= tripped_ns}
                    for topic, rows in probe.pressures.items()}
            joints = {tuple(row[1:]) for row in probe.joints if row[0] >= tripped_ns}
        assert held.pop('supply_pressure') == {burst + STANDARD_ATMOSPHERE}
        assert all(len(values) == 1 for values in held.values()), 'the rest: held'
        assert len(joints) == 1
        status = probe.wait_for_diagnostics(lambda d: d['halted'] == 'true', 'halted')
        assert status['level'] == 2 and 'published at burst_pressure' in status['message']
        assert float(status['supply_pressure_saturated_at']) == burst
        refused = probe._result(probe.reset_client.call_async(Trigger.Request()))
        assert not refused.success, 'a reset at 1 m^3/s (an impossible state) is refused'
        step_to(probe, INITIAL_FLOW)  # a lower flow: the model advances again
        reset_ns = probe.reset()
        probe.next_tick()
        expected = steady_state(reference, INITIAL_FLOW)[P_S] + STANDARD_ATMOSPHERE
        assert probe.first_after(reset_ns)[1] == pytest.approx(expected, rel=1e-9)
        status = probe.wait_for_diagnostics(lambda d: d['halted'] == 'false', 'running again')
        assert status['supply_pressure_saturated_at'] == ''


def test_the_local_dask_cluster_listens_on_loopback_only(tmp_path):
    """A tolerance study's cluster, watched while it runs: every listening socket's address."""
    process = subprocess.Popen(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'tolerance', '--vary', 'd_c=±2%',
         '--samples', '16', '--workers', '2', '--out', str(tmp_path / 'tolerance')],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    seen = set()
    try:
        root = psutil.Process(process.pid)
        while process.poll() is None:
            for member in [root, *root.children(recursive=True)]:
                try:
                    seen |= {(c.laddr.ip, c.laddr.port)
                             for c in member.net_connections(kind='inet')
                             if c.status == psutil.CONN_LISTEN}
                except (psutil.NoSuchProcess, psutil.AccessDenied):
                    pass
            time.sleep(0.05)
    finally:
        out, err = process.communicate(timeout=TIMEOUT)
    assert process.returncode == 0, err
    assert 'yield' in out or 'percentiles' in out or 'P_1_percent' in out
    assert len(seen) >= 3, f'the cluster was seen listening: {seen}'  # scheduler, workers
    assert {ip for ip, _ in seen} <= {'127.0.0.1'}, seen
    assert 'Dask dashboard' not in err
