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
The FMU of `valve-sim fmu`, checked by an independent master: FMPy.

The FMU is built once for the module by the command itself. FMPy validates it, runs
the paper's step through it at a 1 ms communication step against `valve-sim simulate`
recording every 1 ms, and drives instances of it directly through FMI 2.0 calls:
two at once, bad inputs, refused parameter changes, an overpressure and a divergence.
"""

import csv
from ctypes import byref
import json
import math
import os
from pathlib import Path
import shutil
import site
import subprocess
import sys
import tracemalloc
import zipfile

import numpy as np
import pytest
from test_cli import valve_sim
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP
from valve_sim.analysis.steps.measures import MEASURE_NAMES, step_measures
from valve_sim.core.errors import BuildError
from valve_sim.core.model import P_S, X
from valve_sim.core.parameters import PARAMETERS, SPECS
from valve_sim.core.simulation import FlowStep, simulate
from valve_sim.core.steady_state import cracking_pressure, steady_state, with_preset_pressure
from valve_sim.fmu.environment import master_environment
from valve_sim.fmu.export_binary import compile_library, missing_tools
from valve_sim.fmu.fmi_calls import MAX_COMMUNICATION_STEP

fmpy = pytest.importorskip('fmpy')
from fmpy.fmi1 import calloc, FMICallException, free  # noqa: E402, I100 (only with fmpy)
from fmpy.fmi2 import (  # noqa: E402
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2Discard,
    fmi2Error,
    fmi2OK,
    fmi2Warning,
    FMU2Slave,
)
from fmpy.logging import addLoggerProxy  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402


# The paper's step, simulate's default: 5 -> 20 L/min at 0.25 s, to 1.25 s; 1 ms steps.
Q0, Q1 = REFERENCE_FLOW_STEP.initial_flow, REFERENCE_FLOW_STEP.final_flow
STEP_TIME, END_TIME = REFERENCE_FLOW_STEP.step_time, REFERENCE_FLOW_STEP.end_time
INTERVAL = 1e-3
OUTPUTS = ('supply_pressure', 'main_valve_displacement', 'relief_flow', 'halted')


@pytest.fixture(scope='module')
def fmu(tmp_path_factory):
    """Build the FMU with `valve-sim fmu`; return its path (its binary compiled once, cached)."""
    if missing_tools():  # like fmpy missing: this machine cannot build one
        pytest.skip(missing_tools())
    path = tmp_path_factory.mktemp('fmu') / 'valve.fmu'
    result = valve_sim('fmu', '--out', str(path))
    assert path.is_file() and 'ReliefValve' in result.stderr
    return path


@pytest.fixture(scope='module')
def unzipped(fmu, tmp_path_factory):
    """Extract the FMU once; return the folder and its model description (direct FMI calls)."""
    folder = tmp_path_factory.mktemp('unzipped')
    fmpy.extract(str(fmu), str(folder))
    return folder, fmpy.read_model_description(str(fmu))


LOGS = {}  # instance name: [(status, message)] it logged


def _logged(_environment, instance, status, category, message):
    LOGS.setdefault(instance.decode(), []).append((status, message.decode(), category))


# One set for all instances: FMPy's logger proxy (which formats the message as a C
# master would) keeps one logger for the process.
CALLBACKS = fmi2CallbackFunctions(
    logger=fmi2CallbackLoggerTYPE(_logged),
    allocateMemory=fmi2CallbackAllocateMemoryTYPE(calloc),
    freeMemory=fmi2CallbackFreeMemoryTYPE(free),
)
addLoggerProxy(byref(CALLBACKS))


class Valve:
    """One FMU instance driven by FMI 2.0 calls through FMPy, its log kept."""

    def __init__(self, unzipped, name, parameters=None, strings=None, logging=True):
        folder, self.description = unzipped
        self.refs = {v.name: v.valueReference for v in self.description.modelVariables}
        assert name not in LOGS, 'one name per instance: the log is kept by name'
        self.log = LOGS[name] = []
        self.fmu = FMU2Slave(
            guid=self.description.guid, unzipDirectory=str(folder),
            modelIdentifier=self.description.coSimulation.modelIdentifier, instanceName=name,
        )
        self.fmu.instantiate(callbacks=CALLBACKS, loggingOn=logging)
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.set_values(**(parameters or {}))
        for key, value in (strings or {}).items():
            self.fmu.setString([self.refs[key]], [value])
        self.time = 0.0

    def initialise(self):
        self.fmu.exitInitializationMode()
        return self

    def set_values(self, **values):
        for name, value in values.items():
            self.fmu.setReal([self.refs[name]], [value])

    def get(self, *names):
        return self.fmu.getReal([self.refs[name] for name in names])

    def step(self, size=INTERVAL):
        self.fmu.doStep(currentCommunicationPoint=self.time, communicationStepSize=size)
        self.time += size

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


def test_fmpy_validates_the_fmu_and_its_variables_carry_units_and_sources(fmu, reference):
    assert validate_fmu(str(fmu)) == []
    description = fmpy.read_model_description(str(fmu), validate=True)
    assert description.fmiVersion == '2.0' and description.coSimulation is not None
    assert '64-bit Linux only' in description.description
    with zipfile.ZipFile(fmu) as packed:  # valve_sim's binary only, with its licences
        names = packed.namelist()
        assert [n for n in names if n.startswith('binaries/')] == [
            'binaries/linux64/ReliefValve.so']
        assert 'Permission is hereby granted' in packed.read(
            'documentation/licenses/pythonfmu-export.txt').decode()
        assert 'BSD 2-Clause' in packed.read('documentation/licenses/fmi2-headers.txt').decode()
    experiment = description.defaultExperiment
    start_stop_step = (experiment.startTime, experiment.stopTime, experiment.stepSize)
    assert start_stop_step == ('0.0', '1.0', '0.001')
    variables = {v.name: v for v in description.modelVariables}
    for spec in PARAMETERS:
        variable = variables[spec.name]
        assert (variable.causality, variable.variability) == ('parameter', 'tunable')
        assert variable.unit == spec.unit and spec.source in variable.description
        assert float(variable.min) == spec.minimum and float(variable.max) == spec.maximum
    assert {n: float(variables[n].start) for n in SPECS} == reference
    assert float(variables['preset_pressure'].start) == cracking_pressure(reference)
    assert variables['step_size'].variability == 'tunable'
    assert variables['initial_state'].variability == 'fixed'
    assert (variables['inlet_flow'].causality, variables['inlet_flow'].unit) == (
        'input', 'm^3/s')
    assert (variables['tank_pressure'].causality, variables['tank_pressure'].unit) == (
        'input', 'Pa')
    for name in ('supply_pressure', 'intermediate_pressure', 'pilot_pressure',
                 'poppet_chamber_pressure'):
        assert (variables[name].causality, variables[name].unit) == ('output', 'Pa')
        assert 'gauge' in variables[name].description
    for name in ('main_valve_displacement', 'poppet_displacement'):
        assert (variables[name].causality, variables[name].unit) == ('output', 'm')
    assert (variables['relief_flow'].causality, variables['relief_flow'].unit) == (
        'output', 'm^3/s')


@pytest.fixture(scope='module')
def offline(tmp_path_factory):
    """`valve-sim simulate` of the paper's step recording every 1 ms: (CSV rows, measures)."""
    path = tmp_path_factory.mktemp('simulate') / 'step.csv'
    result = valve_sim('simulate', '--record-interval', str(INTERVAL), '--csv', str(path),
                       '--json')
    with open(path) as stream:
        rows = list(csv.DictReader(stream))
    return rows, json.loads(result.stdout)


def test_fmpy_runs_the_papers_step_as_simulate_does(fmu, offline):
    signal = np.array(
        [(0.0, Q0, 0.0), (STEP_TIME, Q0, 0.0), (STEP_TIME, Q1, 0.0), (END_TIME, Q1, 0.0)],
        dtype=[('time', float), ('inlet_flow', float), ('tank_pressure', float)],
    )
    result = fmpy.simulate_fmu(
        str(fmu), start_time=0.0, stop_time=END_TIME, output_interval=INTERVAL, input=signal,
        output=list(OUTPUTS),
    )
    rows, measures = offline
    assert len(result) == len(rows) == round(END_TIME / INTERVAL) + 1
    time = np.array([float(row['time_s']) for row in rows])
    np.testing.assert_allclose(result['time'], time, rtol=0, atol=1e-9)
    for name in ('supply_pressure', 'main_valve_displacement', 'relief_flow'):
        column = next(key for key in rows[0] if key.startswith(name + '_'))
        expected = np.array([float(row[column]) for row in rows])
        # The CSV holds 10 significant digits: 5e-10 relative of rounding at most.
        np.testing.assert_allclose(result[name], expected, rtol=1e-9, atol=0)
    assert not result['halted'].any()
    fmu_measures = step_measures(
        result['time'], result['supply_pressure'], result['main_valve_displacement'],
        STEP_TIME, 1,
    ).as_dict()
    assert measures['reasons'] == fmu_measures['reasons'] == {}
    assert {name: fmu_measures[name] for name in MEASURE_NAMES} == {
        name: measures[name] for name in MEASURE_NAMES
    }


def trace(valve, steps, size=INTERVAL):
    """Step valve steps times; return the supply pressure after each step."""
    pressures = []
    for _ in range(steps):
        valve.step(size)
        pressures.append(valve.get('supply_pressure')[0])
    return np.array(pressures)


def test_two_instances_with_different_parameters_do_not_interfere(unzipped, reference):
    lower = with_preset_pressure(reference, 6e6)
    first = Valve(unzipped, 'first', {'preset_pressure': 6e6}).initialise()
    second = Valve(unzipped, 'second').initialise()
    assert first.get('pilot_spring_preload') == [lower['pilot_spring_preload']]
    assert first.get('supply_pressure') == [steady_state(lower, Q0)[P_S]]
    assert second.get('supply_pressure') == [steady_state(reference, Q0)[P_S]]
    first.set_values(inlet_flow=Q1)
    second.set_values(inlet_flow=Q1)
    traces = {first: [], second: []}
    for _ in range(200):  # interleaved, as a master steps two valves
        for valve in (first, second):
            traces[valve] += trace(valve, 1).tolist()
    for valve in (first, second):
        valve.close()
    for valve, params in ((first, lower), (second, reference)):  # each as if alone
        offline = simulate(params, FlowStep(Q0, Q1, 0.0, 0.2), record_interval=INTERVAL)
        np.testing.assert_allclose(traces[valve], offline['supply_pressure'][1:], rtol=1e-12)
    assert abs(traces[first][-1] - traces[second][-1]) > 5e5  # 1 MPa lower preset


def test_any_communication_step_carries_the_remainder_over(unzipped):
    """1 ms steps, 0.3333 ms steps, 1 us steps: the same state at the same time."""
    valves = [Valve(unzipped, f'valve{i}').initialise() for i in range(3)]
    for valve in valves:
        valve.set_values(inlet_flow=Q1)
    trace(valves[0], 50)
    while valves[1].time + 3.333e-4 < 0.05:
        valves[1].step(3.333e-4)
    valves[1].step(0.05 - valves[1].time)
    trace(valves[2], 100, 1e-6)
    valves[2].step(0.05 - valves[2].time)
    names = ('supply_pressure', 'pilot_pressure', 'main_valve_displacement', 'relief_flow')
    results = [valve.get(*names) for valve in valves]
    for valve in valves:
        valve.close()
    assert results[1] == results[0] and results[2] == results[0]


def test_a_bad_input_or_parameter_change_is_refused_logged_and_the_valve_goes_on(
    unzipped, reference
):
    valve = Valve(unzipped, 'refusing').initialise()
    good = Valve(unzipped, 'good').initialise()
    trace(valve, 5)
    held = valve.get(*OUTPUTS[:3])
    bad = [
        {'inlet_flow': math.nan}, {'inlet_flow': -1e-4}, {'inlet_flow': 1.0},
        {'tank_pressure': math.inf}, {'main_valve_mass': math.nan},
        {'preset_pressure': 1e9}, {'step_size': 1.0},
    ]
    for values in bad:
        valve.set_values(**values)
        with pytest.raises(FMICallException) as refusal:
            valve.step()
        assert refusal.value.status == fmi2Discard  # not fmi2OK, and no crash
        status, message, _ = valve.log[-1]
        assert status == fmi2Error and 'refused' in message, values
        assert valve.get(*OUTPUTS[:3]) == held  # nothing integrated
        valve.set_values(inlet_flow=Q0, tank_pressure=0.0)
    assert valve.get('main_valve_mass', 'preset_pressure', 'step_size') == [
        reference['main_valve_mass'], cracking_pressure(reference), 1e-5
    ]  # the refused parameters are back at the values in use
    trace(good, 5)
    valve.set_values(inlet_flow=Q1)
    good.set_values(inlet_flow=Q1)
    assert np.array_equal(trace(valve, 20), trace(good, 20))  # as if nothing bad came
    valve.close()
    good.close()


def test_bad_steps_a_tank_below_vacuum_and_steps_after_terminate_are_discarded_with_reasons(
    unzipped
):
    valve = Valve(unzipped, 'bad steps').initialise()
    held = valve.get(*OUTPUTS[:3])
    bad = [  # (time, step, what the reason names)
        (0.0, math.inf, 'communicationStepSize must be finite, got inf'),
        (math.nan, INTERVAL, 'currentCommunicationPoint must be finite, got nan'),
        (0.0, 1e6, f'0 to {MAX_COMMUNICATION_STEP:g} s'),
        (0.0, -INTERVAL, 'communicationStepSize must be 0 to'),
        (0.5, INTERVAL, 'steps forward from there only'),
    ]
    for time, size, reason in bad:
        with pytest.raises(FMICallException) as refusal:
            valve.fmu.doStep(currentCommunicationPoint=time, communicationStepSize=size)
        assert refusal.value.status == fmi2Discard, reason  # not fmi2Fatal
        assert valve.log[-1][0] == fmi2Error and reason in valve.log[-1][1]
    valve.set_values(tank_pressure=-1e6)  # gauge: 0.9 MPa below vacuum at 101325 Pa ambient
    with pytest.raises(FMICallException) as refusal:
        valve.step()
    assert refusal.value.status == fmi2Discard and 'below vacuum' in valve.log[-1][1]
    assert valve.get(*OUTPUTS[:3]) == held  # nothing integrated
    with pytest.raises(FMICallException) as error:
        valve.fmu.getReal([10**6])  # no such variable: fmi2Error, logged, the instance kept
    assert error.value.status == fmi2Error
    assert valve.log[-1] == (fmi2Error, 'getReal: KeyError: 1000000', b'logStatusError')
    valve.set_values(tank_pressure=0.0)
    valve.step()  # the instance goes on
    valve.fmu.terminate()
    with pytest.raises(FMICallException) as refusal:
        valve.step()
    assert refusal.value.status == fmi2Discard and 'after terminate' in valve.log[-1][1]
    valve.fmu.freeInstance()


def test_a_failed_start_is_an_error_with_its_reason_and_the_instance_can_be_reset(
    unzipped, reference
):
    """fmi2ExitInitializationMode at a NaN flow: fmi2Error; fmi2Reset, a good flow: it runs."""
    valve = Valve(unzipped, 'failed start', {'inlet_flow': math.nan})
    with pytest.raises(FMICallException) as error:
        valve.initialise()
    assert error.value.status == fmi2Error
    status, message, category = valve.log[-1]
    assert (status, category) == (fmi2Error, b'logStatusError')
    assert message.startswith('exitInitializationMode: ParameterError: the FMU could not start: '
                              'input refused: inlet flow must be finite')
    valve.fmu.reset()
    valve.fmu.setupExperiment(startTime=0.0)
    valve.fmu.enterInitializationMode()
    valve.set_values(inlet_flow=Q1)
    valve.initialise()
    valve.step()
    assert valve.get('supply_pressure')[0] == pytest.approx(steady_state(reference, Q1)[P_S],
                                                            rel=1e-6)
    valve.close()


def test_errors_reach_the_master_with_debug_logging_off_the_rest_only_with_it_on(
    unzipped, reference
):
    failed = Valve(unzipped, 'quiet start', {'inlet_flow': math.nan}, logging=False)
    with pytest.raises(FMICallException):
        failed.initialise()
    failed.close()  # fmi2Terminate and fmi2FreeInstance after fmi2Error: no crash
    valve = Valve(unzipped, 'quiet', {'max_inlet_flow': 10.0}, logging=False).initialise()
    valve.set_values(inlet_flow=math.nan)
    with pytest.raises(FMICallException):
        valve.step()

    def overpressure_and_back():
        valve.set_values(inlet_flow=1.0)
        trace(valve, 3)
        valve.set_values(inlet_flow=Q0)
        trace(valve, 1)  # 'the model advances again': a message of status fmi2OK

    overpressure_and_back()
    assert [(status, category) for status, _, category in failed.log + valve.log] == [
        (fmi2Error, b'logStatusError'), (fmi2Error, b'logStatusError'),
        (fmi2Warning, b'logStatusWarning')]  # the failed start, the NaN step, the overpressure
    valve.fmu.setDebugLogging(True, [])
    overpressure_and_back()
    assert (fmi2OK, b'logAll') == valve.log[-1][::2] and 'advances again' in valve.log[-1][1]
    valve.fmu.setDebugLogging(False, [])
    logged = len(valve.log)
    overpressure_and_back()
    assert [status for status, _, _ in valve.log[logged:]] == [fmi2Warning]
    valve.close()


def test_without_valve_sim_the_fmu_says_why_at_error_level_and_what_to_do(fmu, tmp_path):
    """Run FMPy with debug logging off, in a Python that has FMPy but not valve_sim."""
    script = (
        'import fmpy\n'
        'try:\n'
        f'    fmpy.simulate_fmu({str(fmu)!r}, stop_time=0.01)\n'
        'except Exception as error:\n'
        "    print('raised:', error)\n"
    )
    # -S: no site, so not valve_sim's editable install; the packages by PYTHONPATH.
    result = subprocess.run(
        [sys.executable, '-S', '-c', script], cwd=tmp_path, capture_output=True, text=True,
        env={**os.environ, 'PYTHONPATH': os.pathsep.join(site.getsitepackages())}, timeout=300,
    )
    reason = ('ImportError: the valve_sim FMU cannot start: ModuleNotFoundError: No module named '
              "'valve_sim'")
    assert f'[ERROR] instantiate: {reason}' in result.stdout, (
        result.stdout + result.stderr)
    assert 'pip install' in result.stdout and 'docs/fmu.md' in result.stdout
    assert 'raised: Failed to instantiate' in result.stdout


def slave(tmp_path, name, **values):
    """Return a ReliefValve of this process, started (its calls as the FMI calls make them)."""
    from valve_sim.fmu.relief_valve_slave import ReliefValve

    valve = ReliefValve(instance_name=name, resources=str(tmp_path))
    for key, value in values.items():
        setattr(valve, key, value)
    valve.setup_experiment(0.0)
    valve.exit_initialization_mode()
    return valve


def test_a_long_step_streams_memory_bounded_and_equals_short_steps(tmp_path):
    """10 s in one doStep at a 0.1 ms internal step: 1e5 steps, not an array of them."""
    long, short = (slave(tmp_path, name, step_size=1e-4, inlet_flow=Q1)
                   for name in ('long', 'short'))
    tracemalloc.start()
    try:
        assert long.do_step(0.0, 10.0), long.log_queue
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 400_000  # one array of the whole step: 1.6 MB
    for k in range(100):
        assert short.do_step(k * 0.1, 0.1)
    assert np.array_equal(long.model.state, short.model.state)
    assert long.model.time_ns == short.model.time_ns == 10 * 10**9


def test_the_kernels_are_compiled_at_the_start_not_in_the_first_step(tmp_path):
    """In a fresh process: after exitInitializationMode, doStep compiles nothing more."""
    script = (
        'import sys\n'
        'from valve_sim.core import integrator\n'
        'from valve_sim.fmu.relief_valve_slave import ReliefValve\n'
        f'valve = ReliefValve(instance_name="fresh", resources={str(tmp_path)!r})\n'
        'valve.setup_experiment(0.0)\n'
        'valve.exit_initialization_mode()\n'
        'before = len(integrator.rk4_steps.signatures)\n'
        'assert valve.do_step(0.0, 1e-3)\n'
        'print(before, len(integrator.rk4_steps.signatures))\n'
    )
    result = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                            timeout=300, check=True)
    before, after = map(int, result.stdout.split())
    assert before == after == 1


def test_an_overpressure_halts_the_valve_with_ok_and_a_warning(unzipped, reference):
    valve = Valve(unzipped, 'overpressure', {'max_inlet_flow': 10.0}).initialise()
    valve.set_values(inlet_flow=1.0)
    trace(valve, 3)  # fmi2OK throughout: no exception
    assert valve.fmu.getBoolean([valve.refs['halted']]) == [True]
    assert valve.get('supply_pressure') == [reference['burst_pressure']]
    warnings = [message for status, message, _ in valve.log if status == fmi2Warning]
    assert len(warnings) == 1 and 'overpressure' in warnings[0]
    valve.set_values(inlet_flow=Q0)  # a new input: the valve advances again
    pressures = trace(valve, 50)
    assert valve.fmu.getBoolean([valve.refs['halted']]) == [False]
    assert np.all(pressures < reference['burst_pressure'])
    valve.close()


def test_a_valve_the_step_cannot_integrate_does_not_start_and_can_be_reset(unzipped, reference):
    # A 0.1 g main valve on a 1 mm^3 pilot chamber of stiff water rings beyond the sub-steps
    # allowed at 100 us: the FMU does not start it (core/step_check.py): fmi2Error with the
    # reason, then a reset.
    valve = Valve(unzipped, 'refused', {'main_valve_mass': 1e-4, 'main_valve_damping': 1e4,
                                        'pilot_volume': 1e-9, 'bulk_modulus': 1e10,
                                        'step_size': 1e-4})
    with pytest.raises(FMICallException) as refusal:
        valve.initialise()
    assert refusal.value.status == fmi2Error
    assert any('cannot be integrated' in entry[1] for entry in valve.log), valve.log
    valve.fmu.reset()
    valve.fmu.setupExperiment(startTime=0.0)
    valve.fmu.enterInitializationMode()
    valve.set_values(**{name: reference[name] for name in (
        'main_valve_mass', 'main_valve_damping', 'pilot_volume', 'bulk_modulus')})
    valve.initialise()
    assert np.all(np.isfinite(trace(valve, 10)))
    assert valve.fmu.getBoolean([valve.refs['halted']]) == [False]
    valve.close()


def test_the_start_closed_or_at_the_steady_state_of_the_inputs(unzipped, reference):
    names = ('supply_pressure', 'intermediate_pressure', 'pilot_pressure',
             'poppet_chamber_pressure', 'main_valve_displacement', 'poppet_displacement')
    closed = Valve(unzipped, 'closed', strings={'initial_state': 'closed'}).initialise()
    assert closed.get(*names) == [steady_state(reference, 0.0)[i] for i in (0, 1, 2, 3, X, 6)]
    filling = trace(closed, 5)  # from the inlet flow
    assert filling[0] > 0.0 and np.all(np.diff(filling) > 0.0)
    tank = 1e6
    steady = Valve(unzipped, 'steady', {'tank_pressure': tank}).initialise()
    assert steady.get(*names) == [steady_state(reference, Q0, tank_pressure=tank)[i]
                                  for i in (0, 1, 2, 3, X, 6)]
    main, pilot, leakage = steady.get('main_stage_flow', 'pilot_flow', 'seat_leakage_flow')
    assert steady.get('relief_flow') == [main + pilot + leakage]
    assert main + pilot + leakage == pytest.approx(Q0, rel=1e-9)  # steady: all flow relieved
    wrong = Valve(unzipped, 'wrong', strings={'initial_state': '%s%n 100%'})
    with pytest.raises(FMICallException) as refusal:
        wrong.initialise()
    assert refusal.value.status == fmi2Error  # the '%' reach the logger's format doubled:
    assert "initial_state must be one of steady, closed, got '%s%n 100%'" in wrong.log[-1][1]
    for valve in (closed, steady, wrong):
        valve.close()


def test_preset_pressure_and_the_model_parameters_are_tunable_as_in_valve_node(
    unzipped, reference
):
    valve = Valve(unzipped, 'tuned').initialise()
    valve.set_values(preset_pressure=6.5e6)
    trace(valve, 1)
    assert valve.get('pilot_spring_preload') == [
        with_preset_pressure(reference, 6.5e6)['pilot_spring_preload']
    ]
    valve.set_values(main_spring_stiffness=reference['main_spring_stiffness'] * 1.1)
    trace(valve, 1)
    retuned = {
        **with_preset_pressure(reference, 6.5e6),
        'main_spring_stiffness': reference['main_spring_stiffness'] * 1.1,
    }
    assert valve.get('preset_pressure') == [pytest.approx(cracking_pressure(retuned), rel=1e-12)]
    assert trace(valve, 300)[-1] == pytest.approx(steady_state(retuned, Q0)[P_S], rel=1e-3)
    valve.close()


def test_fmpy_ends_a_run_at_a_nan_input_with_what_came_before(fmu):
    signal = np.array(
        [(0.0, Q0, 0.0), (0.01, Q0, 0.0), (0.01, math.nan, 0.0), (0.02, math.nan, 0.0)],
        dtype=[('time', float), ('inlet_flow', float), ('tank_pressure', float)],
    )
    result = fmpy.simulate_fmu(str(fmu), stop_time=0.02, output_interval=INTERVAL,
                               input=signal, output=['supply_pressure'])
    assert result['time'][-1] == pytest.approx(0.01)  # the step that met the NaN refused
    assert np.all(np.isfinite(result['supply_pressure']))


def c_master(unzipped, tmp_path, path, *flows):
    """Compile test/fmu_c_master.c, run it with PATH and the environment of docs/fmu.md."""
    compiler = shutil.which('cc') or shutil.which('gcc')
    if compiler is None:
        pytest.skip('no C compiler')
    folder, description = unzipped
    master = tmp_path / 'fmu_c_master'
    if not master.exists():
        headers = Path(fmpy.__file__).parent / 'c-code'
        subprocess.run([compiler, '-O1', f'-I{headers}', '-o', str(master),
                        str(Path(__file__).parents[1] / 'fmu_c_master.c'), '-ldl', '-lm'],
                       check=True)
    refs = {v.name: v.valueReference for v in description.modelVariables}
    return subprocess.run(
        [str(master), str(folder / 'binaries' / 'linux64' / 'ReliefValve.so'),
         (folder / 'resources').as_uri(), description.guid, str(refs['inlet_flow']),
         str(refs['supply_pressure']), *(f if isinstance(f, str) else repr(f) for f in flows)],
        env={**os.environ, 'PATH': path, **master_environment()},
        capture_output=True, text=True, timeout=300,
    )


def test_a_c_master_runs_the_papers_step_and_exits_cleanly_from_any_shell(
    unzipped, offline, tmp_path
):
    """
    The FMU loaded as OpenModelica, Hopsan and fmi_adapter load it: dlopen from C.

    With the environment of docs/fmu.md (valve_sim.fmu.environment), from a shell with
    this environment's bin/ first on PATH (activated) and from one with no Python on
    PATH: the paper's step as `simulate` gives it, three bad steps refused with
    fmi2Discard first, a logger that aborts on a NULL category, and after fmi2Terminate,
    fmi2FreeInstance and dlclose, a normal exit: status 0.
    """
    activated = os.pathsep.join([str(Path(sys.executable).parent), os.environ['PATH']])
    result = c_master(unzipped, tmp_path, activated, Q0, Q1, STEP_TIME, END_TIME, INTERVAL,
                      'refuse')
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stderr.count(': status 2\n') == 3  # the three bad steps: fmi2Discard
    pressures = np.array([float(line.split()[1]) for line in result.stdout.splitlines()])
    rows, _ = offline
    expected = np.array([float(row['supply_pressure_Pa']) for row in rows[1:]])
    np.testing.assert_allclose(pressures, expected, rtol=1e-9, atol=0)
    bare = c_master(unzipped, tmp_path, '/usr/bin:/bin', Q0, Q1, STEP_TIME, 0.01, INTERVAL)
    assert bare.returncode == 0, bare.stderr[-3000:]
    assert len(bare.stdout.splitlines()) == 10
    failed = c_master(unzipped, tmp_path, '/usr/bin:/bin', math.nan, Q1, STEP_TIME, 0.01,
                      INTERVAL, 'failstart')  # fmi2Error, then terminate, free, dlclose
    assert failed.returncode == 0, failed.stderr[-3000:]
    assert ('[c_master status 3 logStatusError] exitInitializationMode: ParameterError: '
            'the FMU could not start') in failed.stderr


def test_no_compiler_or_a_failed_compilation_is_one_line(tmp_path, monkeypatch):
    """A BuildError (a ValveSimError: the CLI prints it in one line); nothing half-built."""
    target = tmp_path / 'cache' / 'libpythonfmu-export.so'
    monkeypatch.setenv('CXX', str(tmp_path / 'no-such-compiler'))
    with pytest.raises(BuildError, match=r'needs a C\+\+ compiler .* found no compiler$'):
        compile_library(target, say=print)
    monkeypatch.setenv('CXX', shutil.which('false'))
    with pytest.raises(BuildError, match='failed .false exit 1.: its command and messages are in'
                       ) as failed:
        compile_library(target, say=print)
    assert '\n' not in str(failed.value) and not target.exists()
    assert [p.name for p in target.parent.iterdir()] == ['build.log']


def test_the_command_builds_its_parameters_in_as_defaults(tmp_path, reference):
    path = tmp_path / 'tuned.fmu'
    valve_sim('fmu', '--out', str(path), '--set', 'd_c=1.2e-3', '--preset-pressure', '6.5e6',
              '--step-size', '5e-6', '--set', 'ambient_pressure=9e4')
    variables = {v.name: v for v in fmpy.read_model_description(str(path)).modelVariables}
    params = with_preset_pressure({**reference, 'damping_orifice_diameter': 1.2e-3}, 6.5e6)
    assert {name: float(variables[name].start) for name in SPECS} == params
    assert float(variables['preset_pressure'].start) == pytest.approx(6.5e6, rel=1e-9)
    assert float(variables['step_size'].start) == 5e-6
    result = fmpy.simulate_fmu(str(path), stop_time=0.002, output_interval=INTERVAL,
                               output=['supply_pressure'])
    assert result['supply_pressure'][0] == steady_state(params, Q0)[P_S]
    result = fmpy.simulate_fmu(str(path), stop_time=0.002, output_interval=INTERVAL,
                               start_values={'tank_pressure': -8.9e4})  # vacuum: -9e4 gauge
    assert len(result) == 3 and result['supply_pressure'].all()
    with pytest.raises(FMICallException) as refused:
        fmpy.simulate_fmu(str(path), stop_time=0.002, start_values={'tank_pressure': -9.1e4})
    assert refused.value.status == fmi2Error
    refused = valve_sim('fmu', '--out', str(tmp_path / 'valve.zip'), check=False)
    assert refused.returncode == 1 and '--out must name a .fmu file' in refused.stderr


def test_a_d_c_change_before_start_and_between_steps_solves_the_cracking_point_once(
    monkeypatch, tmp_path, reference
):
    # The slave in this process (not through FMI) with the cracking-point solver counted:
    # a change is planned once (core.retuning.plan_change) and applied once.
    from valve_sim.core import retuning, steady_state
    from valve_sim.fmu.relief_valve_slave import ReliefValve

    solve, solves = steady_state.cracking_pressure, []

    def counted(*args, **kwargs):
        solves.append(args)
        return solve(*args, **kwargs)

    monkeypatch.setattr(steady_state, 'cracking_pressure', counted)
    monkeypatch.setattr(retuning, 'cracking_pressure', counted)
    d_c = reference['damping_orifice_diameter']
    valve = ReliefValve(instance_name='counted', resources=str(tmp_path))  # the defaults
    valve.setup_experiment(0.0)
    valve.damping_orifice_diameter = d_c * 1.2
    solves.clear()
    valve.exit_initialization_mode()
    assert len(solves) == 1 and valve.model is not None, valve.log_queue
    assert valve.model.params['damping_orifice_diameter'] == d_c * 1.2
    assert valve.preset_pressure == solve(valve.model.params) != solve(reference)
    assert valve.do_step(0.0, INTERVAL)
    valve.damping_orifice_diameter = d_c * 1.4
    solves.clear()
    assert valve.do_step(INTERVAL, INTERVAL)
    assert len(solves) == 1
    assert valve.model.params['damping_orifice_diameter'] == d_c * 1.4
    assert valve.preset_pressure == solve(valve.model.params)
