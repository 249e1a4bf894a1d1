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
"""

from valve_sim.analysis.paper import (
    REFERENCE_SCENARIO,
    STUDY_PARAMETERS,
    STUDY_VARIATIONS,
    TABLE2_CHANGES,
)
from valve_sim.core.parameters import scaled


PROTOCOLS = {
    'held-preset': 'pilot spring preload re-solved per case: the main valve cracks at the '
    'preset pressure in every case (the paper: preset pressure 7 MPa)',
    'frozen-preload': 'pilot spring preload of the parameter file in every case: '
    'the preset moves with the varied parameters',
}
DEFAULT_PROTOCOL = 'held-preset'


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
        raise ValueError(f'unknown study protocol {protocol!r}; known: {", ".join(PROTOCOLS)}')
    return case


def protocol_preset(protocol, preset_pressure):
    """Return the preset a case of this protocol is set to: preset_pressure, or None (frozen)."""
    if protocol not in PROTOCOLS:
        raise ValueError(f'unknown study protocol {protocol!r}; known: {", ".join(PROTOCOLS)}')
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
