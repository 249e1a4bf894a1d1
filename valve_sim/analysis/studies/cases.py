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
The cases of the paper's parameter study and the protocol that sets each case's preset.

One definition for `valve-sim study`, calibration checks, tolerance studies and
optimisation: the protocol's preset, and the runner's cases (StudyCase) of the study and
of sampled valves. run_all() runs the paper's study on a runner backend (backend),
run_case() one of its cases here, run_samples() sampled valves; each result of the study
is {'measures', 'poppet', 'case'} (study_result()).
"""

from dataclasses import dataclass
import sys
from typing import Optional

from valve_sim.analysis.paper import (
    REFERENCE_FLOW_STEP,
    STUDY_PARAMETERS,
    STUDY_VARIATIONS,
    TABLE2_CHANGES,
)
from valve_sim.analysis.studies.backend import CORES, open_backend, SerialBackend
from valve_sim.core.errors import ParameterError
from valve_sim.core.flow_step import FlowStep
from valve_sim.core.parameters import scaled


PROTOCOLS = {
    'held-preset': 'pilot spring preload re-solved per case: the main valve cracks at the '
    'preset pressure in every case (the paper: preset pressure 7 MPa)',
    'frozen-preload': 'pilot spring preload of the parameter file in every case: '
    'the preset moves with the varied parameters',
}
DEFAULT_PROTOCOL = 'held-preset'
FIGURE8_PARAMETER = 'm_p'  # Figure 8: the poppet waveforms of the m_p variations


def study_cases():
    """[(label, {symbol: percent})]: the baseline, the one-at-a-time variations, Table 2."""
    cases = [('reference', {})]
    for symbol in STUDY_PARAMETERS:
        cases += [
            (f'{symbol} {percent:+d} %', {symbol: percent})
            for percent in STUDY_VARIATIONS
            if percent
        ]
    cases.append(('table2', dict(TABLE2_CHANGES)))
    return cases


def case_parameters(params, changes, protocol, preset_pressure):
    """
    Return the validated parameters of one case: params scaled by changes {symbol: percent}.

    protocol 'held-preset' re-solves the pilot spring preload so that the main
    valve cracks at preset_pressure [Pa]; 'frozen-preload' keeps it.
    Raises ParameterError or SteadyStateError when the case has no such preload.
    """
    from valve_sim.core.steady_state import with_preset_pressure  # numba, scipy: when used

    case = scaled(params, changes)
    if protocol == 'held-preset':
        case = with_preset_pressure(case, preset_pressure)
    elif protocol != 'frozen-preload':
        raise ParameterError(f'unknown study protocol {protocol!r}; known: {", ".join(PROTOCOLS)}')
    return case


def protocol_preset(protocol, preset_pressure):
    """Return the preset a case of this protocol is set to: preset_pressure, or None (frozen)."""
    if protocol not in PROTOCOLS:
        raise ParameterError(f'unknown study protocol {protocol!r}; known: {", ".join(PROTOCOLS)}')
    return preset_pressure if protocol == 'held-preset' else None


def preset_protocol(protocol, params):
    """
    Return (preset for the cases or None, JSON-ready statement of how each valve was set).

    The preset is the cracking pressure of params (after --preset-pressure).
    """
    from valve_sim.core.steady_state import cracking_pressure

    preset = cracking_pressure(params)
    statement = {
        'protocol': protocol,
        'protocol_meaning': PROTOCOLS[protocol],
        'preset_pressure': preset,
        'nominal_pilot_spring_preload': params['pilot_spring_preload'],
    }
    return protocol_preset(protocol, preset), statement


@dataclass(frozen=True)
class StudyCase:
    """
    One step test of a study, as the runner (studies.runner) takes it; picklable (Dask).

    index: unique within its study (the bookkeeping key); params: the complete model
    parameters (SI), as sampled (validated by the runner: a sample outside a parameter's
    limits is that case's error); preset_pressure [Pa]: the valve is set to crack at it
    before its test (the pilot spring preload y_0 re-solved, as a technician turns the
    screw), None keeps params' preload (frozen preload); flow_step: the inlet-flow step
    test; step_size [s]: the RK4 step; record: the state names whose waveforms the row
    keeps; envelope: the row gets the envelope's decay rate too (measures.ENVELOPE_DECAY).
    """

    index: int
    params: dict
    preset_pressure: Optional[float]
    flow_step: FlowStep
    step_size: float
    record: tuple = ()
    envelope: bool = False

    def fingerprint_fields(self):
        """
        Return the case as results.fingerprint() hashes it.

        The dict a case was before it was a StudyCase (its step test under 'scenario',
        'envelope' only when set), so that a results folder written before resumes.
        """
        fields = {
            'index': self.index,
            'params': self.params,
            'preset_pressure': self.preset_pressure,
            'scenario': self.flow_step,
            'step_size': self.step_size,
            'record': list(self.record),
        }
        if self.envelope:
            fields['envelope'] = True
        return fields


def sample_cases(params, names, values, preset, step_size):
    """Runner cases for sampled values (rows of values, columns of names)."""
    return [
        StudyCase(
            index, {**params, **dict(zip(names, map(float, row)))}, preset,
            REFERENCE_FLOW_STEP, step_size,
        )
        for index, row in enumerate(values)
    ]


def runner_case(index, params, changes, step_size, protocol, preset_pressure):
    """
    Return one case of the study as the runner takes it: params scaled by changes.

    protocol 'held-preset' has the runner re-solve the pilot spring preload so that
    the main valve cracks at preset_pressure [Pa]; 'frozen-preload' keeps it.
    """
    return StudyCase(
        index,
        scaled(params, changes),
        protocol_preset(protocol, preset_pressure),
        REFERENCE_FLOW_STEP,
        step_size,
        record=('poppet_displacement',) if set(changes) <= {FIGURE8_PARAMETER} else (),
        envelope=True,
    )


def study_result(row, protocol, preset_pressure):
    """
    Return a runner row as {'measures': ..., 'poppet': (time, y) or None, 'case': {...}}.

    'case': protocol, preset_pressure_Pa, cracking_pressure_Pa, pilot_spring_preload_m,
    initial_supply_pressure_Pa, initial_main_valve_displacement_m. A case that could not
    run gets every measure None with the reason.
    """
    import numpy as np  # here: commands import this module for their --help
    from valve_sim.analysis.steps.measures import MEASURE_NAMES

    case = {
        'protocol': protocol,
        'preset_pressure_Pa': preset_pressure,
        'cracking_pressure_Pa': row.get('cracking_pressure'),
        'pilot_spring_preload_m': row.get('pilot_spring_preload'),
        'initial_supply_pressure_Pa': row.get('initial_supply_pressure'),
        'initial_main_valve_displacement_m': row.get('initial_main_valve_displacement'),
    }
    if row['error']:
        reasons = dict.fromkeys(MEASURE_NAMES, f'no step response: {row["error"]}')
        return {
            'measures': {**row['measures'], 'reasons': reasons, 'details': {}},
            'poppet': None,
            'case': case,
        }
    measures = {**row['measures'], 'reasons': dict(row['reasons']), 'details': {}}
    if case['initial_main_valve_displacement_m'] <= 0.0:
        measures['details']['note'] = (
            'main stage closed before the step: the valve relieves through the pilot alone'
        )
    waveforms = row.get('waveforms')
    poppet = (
        (np.asarray(waveforms['time']), np.asarray(waveforms['poppet_displacement']))
        if waveforms
        else None
    )
    return {'measures': measures, 'poppet': poppet, 'case': case}


def run_case(params, changes, step_size, protocol=DEFAULT_PROTOCOL, preset_pressure=None):
    """
    Run one case here; returns {'measures', 'poppet', 'case'} as study_result().

    preset_pressure [Pa] defaults to the cracking pressure of params.
    """
    from valve_sim.analysis.studies.runner import evaluate_case
    from valve_sim.core.steady_state import cracking_pressure

    if preset_pressure is None:
        preset_pressure = cracking_pressure(params)
    case = runner_case(0, params, changes, step_size, protocol, preset_pressure)
    return study_result(evaluate_case(case), protocol, preset_pressure)


def run_all(
    params,
    step_size,
    backend,
    results_path,
    protocol=DEFAULT_PROTOCOL,
    preset_pressure=None,
    resume=False,
    progress_stream=sys.stderr,
):
    """
    Run every case on the backend (None: here, serially); returns {label: study_result}.

    Rows stream to results_path (resume: see run_cases); preset_pressure [Pa]
    defaults to the cracking pressure of params.
    """
    from valve_sim.analysis.studies.runner import run_cases
    from valve_sim.core.steady_state import cracking_pressure

    if preset_pressure is None:
        preset_pressure = cracking_pressure(params)
    labelled = study_cases()
    rows, _ = run_cases(
        [
            runner_case(index, params, changes, step_size, protocol, preset_pressure)
            for index, (_, changes) in enumerate(labelled)
        ],
        results_path,
        backend or SerialBackend(),
        resume,
        label='study',
        progress_stream=progress_stream,
    )
    return {
        label: study_result(rows[index], protocol, preset_pressure)
        for index, (label, _) in enumerate(labelled)
    }


def run_samples(
    label, params, names, values, preset, step_size, results_path, scheduler=None,
    workers=CORES, dashboard=None, resume=False, batch_size=None,
):
    """
    Run the sampled valves on the study runner; return their rows in sample order.

    values: one row per valve, one column per parameter of names; preset [Pa] or None
    (sample_cases). Rows stream to results_path (resume continues it); the backend is
    open_backend()'s for command label.
    """
    from valve_sim.analysis.studies.runner import run_cases

    backend = open_backend(label, scheduler, workers, dashboard)
    try:
        results, _ = run_cases(
            sample_cases(params, names, values, preset, step_size),
            results_path,
            backend,
            resume,
            batch_size,
            label=label,
        )
    finally:
        backend.close()
    return [results[index] for index in range(len(values))]
