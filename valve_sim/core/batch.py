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
Batch runs for studies: many parameter sets through one flow step, on the lanes kernel.

simulate_batch() runs the sets LANES at a time through valve_sim.core.lanes and does
not integrate the stretch before the step when the start is a stable steady state:
there the flow is constant and the state is the exact steady state, a fixed point of
RK4 (every stage's derivative is zero), so the integration would only reproduce it
up to rounding. Its samples before the step are then the steady state itself
(docs/speed.md gives the measured difference). An unstable steady state (a linear
mode with Re(lambda) >= 0, valve_sim.core.linear) is integrated as in
simulation.simulate(): there rounding errors grow before the step as they would on a
rig. Each run's outcome is a RunResult: its waveforms or why it failed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Optional

import numpy as np
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import ParameterError, SteadyStateError
from valve_sim.core.flow_step import FlowStep
from valve_sim.core.lanes import advance_lanes
from valve_sim.core.linear import jacobian
from valve_sim.core.simulation import (
    check_schedule,
    recorded_waveforms,
    step_flows,
    Waveforms,
)
from valve_sim.core.steady_state import steady_state
from valve_sim.core.step_check import check_integrable


LANES = 16  # valves simulate_batch advances together (more gives no further gain, bench/)


@dataclass(frozen=True)
class RunResult:
    """
    One run of simulate_batch, in the manner of scipy's OdeResult: the waveforms or the reason.

    waveforms: the run's Waveforms, None when it failed; error: why it failed (the
    ParameterError, SteadyStateError or IntegrationError of its start or its
    integration), None when it succeeded.
    """

    waveforms: Optional[Waveforms] = None
    error: Optional[Exception] = None

    @property
    def success(self) -> bool:
        """Whether the run completed (it has waveforms)."""
        return self.error is None

    @property
    def message(self) -> str:
        """Why the run failed, in one line ('' when it succeeded)."""
        return '' if self.error is None else str(self.error)

    @property
    def status(self) -> int:
        """0: the run completed; 1: it failed (message says why), as scipy's results."""
        return 0 if self.error is None else 1


def steady_lead(flows, initial_flow, record_every):
    """
    Count the steps at the start of a run that hold initial_flow, in whole record intervals.

    From the steady state of initial_flow, these need no integration if it is stable.
    """
    changed = np.flatnonzero(flows != initial_flow)
    first = changed[0] if len(changed) else len(flows)
    return first // record_every * record_every


def is_stable(params, state, inlet_flow):
    """Return whether every linear mode about a steady state decays (all Re(lambda) < 0)."""
    return bool(np.max(np.linalg.eigvals(jacobian(params, state, inlet_flow)).real) < 0.0)


def simulate_batch(
    params_list: Sequence[Mapping[str, float]], flow_step: FlowStep = FlowStep(),
    step_size: float = 1e-5, record_interval: float = 1e-4, lanes: int = LANES,
) -> list[RunResult]:
    """
    Run one flow step for many parameter sets; a list of RunResults, one per set, in order.

    A run's waveforms are those simulate() gives (the same sample times), except that the
    stretch before the step is not integrated but held at the exact steady state
    when that is stable (see the module docstring). A set whose start fails has its
    ParameterError or SteadyStateError as the result's error, a run that diverges
    its IntegrationError; the other sets are not affected. lanes: how many runs the
    kernel advances together.
    """
    record_every = max(1, int(round(record_interval / step_size)))
    flows = step_flows(flow_step, step_size)
    lead = steady_lead(flows, flow_step.initial_flow, record_every)
    results, starts, groups = [None] * len(params_list), {}, {lead: [], 0: []}
    for index, params in enumerate(params_list):
        try:
            state = steady_state(params, flow_step.initial_flow, stable=False)
            check_integrable(params, step_size)
            check_schedule(params, flows)
        except (ParameterError, SteadyStateError) as error:
            results[index] = RunResult(error=error)
            continue
        starts[index] = (state, coefficients(params))
        groups[lead if is_stable(params, state, flow_step.initial_flow) else 0].append(index)
    for skipped, ready in groups.items():
        for first in range(0, len(ready), max(1, lanes)):
            group = ready[first:first + max(1, lanes)]
            records, errors = advance_lanes(
                np.array([starts[index][0] for index in group]),
                flows[skipped:],
                [starts[index][1] for index in group],
                step_size,
                record_every,
                time=skipped * step_size,
            )
            for lane, index in enumerate(group):
                results[index] = RunResult(error=errors[lane]) if errors[lane] else RunResult(
                    recorded_waveforms(
                        starts[index][0],
                        records[lane],
                        flows,
                        record_every,
                        step_size,
                        flow_step.initial_flow,
                        held=skipped // record_every,
                    )
                )
    return results
