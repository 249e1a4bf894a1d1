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

import numpy as np
import pytest
from test_cli import valve_sim
from valve_sim.analysis.measures import MEASURE_NAMES, step_measures
from valve_sim.analysis.paper import REFERENCE_SCENARIO
from valve_sim.core.model import P_S, X
from valve_sim.core.parameters import PARAMETERS, SPECS
from valve_sim.core.steady_state import cracking_pressure, steady_state, with_preset_pressure

fmpy = pytest.importorskip('fmpy')
from fmpy.fmi1 import calloc, FMICallException, free  # noqa: E402, I100 (only with fmpy)
from fmpy.fmi2 import (  # noqa: E402
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2Discard,
    fmi2Error,
)
from fmpy.logging import addLoggerProxy  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402


# The paper's step, simulate's default: 5 -> 20 L/min at 0.25 s, to 1.25 s; 1 ms steps.
Q0, Q1 = REFERENCE_SCENARIO.initial_flow, REFERENCE_SCENARIO.final_flow
STEP_TIME, END_TIME = REFERENCE_SCENARIO.step_time, REFERENCE_SCENARIO.end_time
INTERVAL = 1e-3
OUTPUTS = ('supply_pressure', 'main_valve_displacement', 'relief_flow', 'halted')


@pytest.fixture(scope='module')
def fmu(tmp_path_factory):
    """Build the FMU with `valve-sim fmu`; return its path."""
    path = tmp_path_factory.mktemp('fmu') / 'valve.fmu'
    result = valve_sim('fmu', '--out', str(path))
    assert path.is_file() and 'ReliefValve' in result.stderr
    return path


@pytest.fixture(scope='module')
def unzipped(fmu, tmp_path_factory):
    """The FMU extracted once, with its model description: for direct FMI calls."""
    folder = tmp_path_factory.mktemp('unzipped')
    fmpy.extract(str(fmu), str(folder))
    return folder, fmpy.read_model_description(str(fmu))


class Valve:
    """One FMU instance driven by FMI 2.0 calls through FMPy, its log kept."""

    def __init__(self, unzipped, name, parameters=None, strings=None):
        folder, self.description = unzipped
        self.refs = {v.name: v.valueReference for v in self.description.modelVariables}
        self.log = []
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(self._logged)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(byref(callbacks))  # formats the message as a C master would
        self._callbacks = callbacks  # kept alive as long as the instance
        self.fmu = FMU2Slave(
            guid=self.description.guid, unzipDirectory=str(folder),
            modelIdentifier=self.description.coSimulation.modelIdentifier, instanceName=name,
        )
        self.fmu.instantiate(callbacks=callbacks, loggingOn=True)
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.set(**(parameters or {}))
        for key, value in (strings or {}).items():
            self.fmu.setString([self.refs[key]], [value])
        self.time = 0.0

    def _logged(self, _environment, _instance, status, _category, message):
        self.log.append((status, message.decode()))

    def initialise(self):
        self.fmu.exitInitializationMode()
        return self

    def set(self, **values):
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
    assert {n: (variables[n].causality, variables[n].unit) for n in ('inlet_flow',
            'tank_pressure')} == {'inlet_flow': ('input', 'm^3/s'), 'tank_pressure': ('input', 'Pa')}
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


def test_probe(unzipped):
    a = Valve(unzipped, 'a').initialise()
    a.step()
    print(a.get('supply_pressure'))
    a.set(inlet_flow=float('nan'))
    try:
        a.step()
    except FMICallException as e:
        print('EXC', e, e.status)
    print(a.log)
    a.set(inlet_flow=Q0)
    a.step()
    print(a.get('supply_pressure'))
    c = Valve(unzipped, 'c', {'step_size': 5e-5, 'poppet_chamber_volume': 1e-9}).initialise()
    for i in range(3):
        try:
            c.step()
        except FMICallException as e:
            print('EXC', e, e.status)
    print(c.log[-3:], c.fmu.getBoolean([c.refs['halted']]))
    b = Valve(unzipped, 'b', {'max_inlet_flow': 10.0}).initialise()
    b.set(inlet_flow=1.0)
    for i in range(50):
        b.step()
    print(b.log[-3:], b.get('supply_pressure'))
    assert 0
