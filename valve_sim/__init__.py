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
valve_sim: a virtual direct-pressure-sensing water-hydraulic relief valve for ROS 2 test benches.

The package is built in wings, each importing only the wings below it:

    core       the model: parameters, Eqs. (1)-(16), integrator, steady state (numpy, scipy)
    fmu        the model as an FMI 2.0 co-simulation FMU's slave (pythonfmu)
    analysis   step-response measures, signal handling, reference data, plots
    recording  MCAP bags as rosbag2 writes them, CDR tick messages, a bag's signals
    ros        the nodes (valve_node, analyser_node): thin rclpy adapters; replay, demo run
    commands   the `valve-sim` command line: parse, call the library, print
    testing    the test kit for users' suites: a valve_node in lockstep, a pytest fixture

test/lint/test_layering.py keeps it so.

This package is also the library's front door (docs/python.md): `import valve_sim as vs`
gives its verbs, each imported from its wing at first use, so that `import valve_sim`
stays light (no numba, scipy or ROS until a verb needs them):

    vs.Parameters           a valve's parameters: validated when built, immutable, replace()
    vs.FlowStep, vs.TankPressure    the inputs: an inlet-flow step, the tank's pressure
    vs.simulate             a flow-step run -> Waveforms (time [s], states by name, status)
    vs.operating_point      the exact steady state at one flow, with its linear modes
    vs.cracking_pressure    the pressure at which the pilot opens [Pa]
    vs.step_measures        the paper's six step-response measures -> StepMeasures
    vs.read_recording       a bag (MCAP or rosbag2 folder) -> Recording
    vs.recorded_steps       the steps found in a Recording and their measures
    vs.calibrate            fit parameters to a recording or to measures -> CalibrationResult
    vs.simulate_batch       a study: many parameter sets through one flow step -> [RunResult]
    vs.ValveSimError        the root of every error the library raises on purpose
"""

from __future__ import annotations

from importlib import import_module
from typing import Any, TYPE_CHECKING

if TYPE_CHECKING:  # what a type checker sees; at run time __getattr__ imports on first use
    from valve_sim.analysis.calibration.fit import (
        calibrate as calibrate,
        CalibrationProblem as CalibrationProblem,
        CalibrationResult as CalibrationResult,
        FitSettings as FitSettings,
    )
    from valve_sim.analysis.calibration.parameters import (
        fit_parameters as fit_parameters,
    )
    from valve_sim.analysis.calibration.targets import (
        MeasuresTarget as MeasuresTarget,
        RecordingTarget as RecordingTarget,
    )
    from valve_sim.analysis.recorded_steps import (
        analyse as recorded_steps,
    )
    from valve_sim.analysis.steps.measures import (
        step_measures as step_measures,
        StepMeasures as StepMeasures,
    )
    from valve_sim.core.batch import (
        RunResult as RunResult,
        simulate_batch as simulate_batch,
    )
    from valve_sim.core.errors import (
        CalibrationError as CalibrationError,
        InputFileError as InputFileError,
        IntegrationError as IntegrationError,
        ParameterError as ParameterError,
        SteadyStateError as SteadyStateError,
        ValveSimError as ValveSimError,
    )
    from valve_sim.core.flow_step import (
        FlowStep as FlowStep,
        LITRE_PER_MINUTE as LITRE_PER_MINUTE,
        TankPressure as TankPressure,
    )
    from valve_sim.core.simulation import (
        simulate as simulate,
        Waveforms as Waveforms,
    )
    from valve_sim.core.steady_state import (
        cracking_pressure as cracking_pressure,
    )
    from valve_sim.core.valve import (
        operating_point as operating_point,
        OperatingPoint as OperatingPoint,
        Parameters as Parameters,
    )
    from valve_sim.recording.signal_reader import (
        read_recording as read_recording,
        Recording as Recording,
    )


__version__ = '0.1.0'

# name -> the module it lives in (one implementation each; this file only points at it).
_EXPORTS = {
    'Parameters': 'valve_sim.core.valve',
    'OperatingPoint': 'valve_sim.core.valve',
    'operating_point': 'valve_sim.core.valve',
    'FlowStep': 'valve_sim.core.flow_step',
    'TankPressure': 'valve_sim.core.flow_step',
    'LITRE_PER_MINUTE': 'valve_sim.core.flow_step',
    'simulate': 'valve_sim.core.simulation',
    'Waveforms': 'valve_sim.core.simulation',
    'cracking_pressure': 'valve_sim.core.steady_state',
    'simulate_batch': 'valve_sim.core.batch',
    'RunResult': 'valve_sim.core.batch',
    'step_measures': 'valve_sim.analysis.steps.measures',
    'StepMeasures': 'valve_sim.analysis.steps.measures',
    'calibrate': 'valve_sim.analysis.calibration.fit',
    'CalibrationProblem': 'valve_sim.analysis.calibration.fit',
    'CalibrationResult': 'valve_sim.analysis.calibration.fit',
    'FitSettings': 'valve_sim.analysis.calibration.fit',
    'fit_parameters': 'valve_sim.analysis.calibration.parameters',
    'RecordingTarget': 'valve_sim.analysis.calibration.targets',
    'MeasuresTarget': 'valve_sim.analysis.calibration.targets',
    'read_recording': 'valve_sim.recording.signal_reader',
    'Recording': 'valve_sim.recording.signal_reader',
    'recorded_steps': 'valve_sim.analysis.recorded_steps',
    'ValveSimError': 'valve_sim.core.errors',
    'ParameterError': 'valve_sim.core.errors',
    'InputFileError': 'valve_sim.core.errors',
    'IntegrationError': 'valve_sim.core.errors',
    'SteadyStateError': 'valve_sim.core.errors',
    'CalibrationError': 'valve_sim.core.errors',
}
_RENAMED = {'recorded_steps': 'analyse'}  # front-door name -> its name in its module

__all__ = [  # literal, so that type checkers see the exports (test_front_door checks it)
    '__version__',
    'Parameters', 'OperatingPoint', 'operating_point', 'FlowStep', 'TankPressure',
    'LITRE_PER_MINUTE', 'simulate', 'Waveforms', 'cracking_pressure', 'simulate_batch',
    'RunResult', 'step_measures', 'StepMeasures', 'calibrate', 'CalibrationProblem',
    'CalibrationResult', 'FitSettings', 'fit_parameters', 'RecordingTarget', 'MeasuresTarget',
    'read_recording', 'Recording', 'recorded_steps', 'ValveSimError', 'ParameterError',
    'InputFileError', 'IntegrationError', 'SteadyStateError', 'CalibrationError',
]


def __getattr__(name: str) -> Any:
    """Import a front-door name from its wing at its first use (PEP 562)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'valve_sim' has no attribute '{name}'")
    value = getattr(import_module(_EXPORTS[name]), _RENAMED.get(name, name))
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
