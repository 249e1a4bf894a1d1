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
optimisation: the protocol's preset, and the runner cases of sampled valves.
run_all() runs the paper's study on a runner backend (study_backend), run_case() one
of its cases here; each result is {'measures', 'poppet', 'case'} (study_result()).
"""

import sys

from valve_sim.analysis.paper import (
    REFERENCE_SCENARIO,
    STUDY_PARAMETERS,
    STUDY_VARIATIONS,
    TABLE2_CHANGES,
)
from valve_sim.core.errors import ParameterError
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


def sample_cases(params, names, values, preset, step_size):
    """Runner cases for sampled values (rows of values, columns of names)."""
    return [
        {
            'index': index,
            'params': {**params, **dict(zip(names, map(float, row)))},
            'preset_pressure': preset,
            'scenario': REFERENCE_SCENARIO,
            'step_size': step_size,
            'record': [],
        }
        for index, row in enumerate(values)
    ]


def runner_case(index, params, changes, step_size, protocol, preset_pressure):
    """
    Return one case of the study as the runner takes it: params scaled by changes.

    protocol 'held-preset' has the runner re-solve the pilot spring preload so that
    the main valve cracks at preset_pressure [Pa]; 'frozen-preload' keeps it.
    """
    return {
        'index': index,
        'params': scaled(params, changes),
        'preset_pressure': protocol_preset(protocol, preset_pressure),
        'scenario': REFERENCE_SCENARIO,
        'step_size': step_size,
        'record': ['poppet_displacement'] if set(changes) <= {FIGURE8_PARAMETER} else [],
        'envelope': True,
    }


def study_result(row, protocol, preset_pressure):
    """
    Return a runner row as {'measures': ..., 'poppet': (time, y) or None, 'case': {...}}.

    'case': protocol, preset_pressure_Pa, cracking_pressure_Pa, pilot_spring_preload_m,
    initial_supply_pressure_Pa, initial_main_valve_displacement_m. A case that could not
    run gets every measure None with the reason.
    """
    import numpy as np  # here: commands import this module for their --help
    from valve_sim.analysis.measures import MEASURE_NAMES

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
    from valve_sim.analysis.study_runner import evaluate_case
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
    from valve_sim.analysis.study_backend import SerialBackend
    from valve_sim.analysis.study_runner import run_cases
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
