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
What the slave's doStep calls share: a communication step checked and streamed.

A communication step is checked first (check_step: finite, forward from the FMU's time, at
most MAX_COMMUNICATION_STEP) and integrated in chunks of CHUNK_STEPS internal steps
(advance_streaming), so memory does not grow with the step and time is proportional to it.
"""

import math

from valve_sim.core.errors import IntegrationError, ParameterError
from valve_sim.core.realtime_model import NS_PER_S


MAX_COMMUNICATION_STEP = 3600.0  # [s] one doStep at most: an hour of model time
CHUNK_STEPS = 8192  # internal steps integrated per call of the model: 64 kB of inputs
NEVER_SKIP_NS = 2**62  # the master's clock is the model's: no lag is ever skipped


def check_step(current_time, step_size, clock_ns):
    """
    Return the end of a communication step [ns]; ParameterError if it is not one to take.

    current_time, step_size [s] as the master gave them; clock_ns: the FMU's time [ns].
    """
    for name, value in (('currentCommunicationPoint', current_time),
                        ('communicationStepSize', step_size)):
        if not math.isfinite(value):
            raise ParameterError(f'{name} must be finite, got {value!r}')
    if not 0.0 <= step_size <= MAX_COMMUNICATION_STEP:
        raise ParameterError(
            f'communicationStepSize must be 0 to {MAX_COMMUNICATION_STEP:g} s (the longest '
            f'step this FMU takes in one call), got {step_size!r} s: split the step'
        )
    if abs(current_time) > 1e9 or round(current_time * NS_PER_S) != clock_ns:
        raise ParameterError(
            f'a step from t = {current_time!r} s: the FMU is at t = {clock_ns / NS_PER_S!r} s '
            'and steps forward from there only'
        )
    return round((current_time + step_size) * NS_PER_S)


def advance_streaming(model, now_ns, inlet_flow, tank_pressure):
    """
    Integrate the model to now_ns [ns] chunk by chunk, the inputs held.

    As RealTimeModel.advance_to in one call, but with CHUNK_STEPS steps at most per
    call. On an IntegrationError (or OverpressureError) the state and model time are put
    back as they were before this call, then it is raised: the step is all or nothing.
    """
    state, time_ns = model.state.copy(), model.time_ns
    chunk_ns = CHUNK_STEPS * round(model.step_size * NS_PER_S)
    try:
        while model.time_ns + chunk_ns < now_ns:
            model.advance_to(model.time_ns + chunk_ns, inlet_flow, NEVER_SKIP_NS, tank_pressure)
        model.advance_to(now_ns, inlet_flow, NEVER_SKIP_NS, tank_pressure)
    except IntegrationError:
        model.state[:] = state
        model.time_ns = time_ns
        raise
