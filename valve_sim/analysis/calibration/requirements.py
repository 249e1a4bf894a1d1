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
What a calibration requires of a fitted valve besides its target: constraints and checks.

A Constraint adds a residual to the fit (its penalty) that is zero while it holds,
so the optimiser is steered back inside: PilotFlowLimit, ModesDecay, CaseRelieves,
and the design rules LandsInsideBore and MainSpringRange. A Check (StudyRelieves)
is too costly for every evaluation: it judges each start's result. Both report
their status in one form (judged()): the requirement's name, its value as text and
whether it is satisfied.
"""

from dataclasses import dataclass, field
import math
from typing import Protocol, runtime_checkable

import numpy as np
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP, TABLE2_CHANGES
from valve_sim.analysis.steps.measures import WINDOW
from valve_sim.analysis.studies.cases import case_parameters, study_cases
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import MODEL_ERRORS
from valve_sim.core.linear import modes
from valve_sim.core.model import flows, X
from valve_sim.core.simulation import LITRE_PER_MINUTE, simulate
from valve_sim.core.steady_state import cracking_pressure, steady_state


# Penalties turn on this far (relative) inside their limits: a least-squares optimum sits a
# hair beyond where a penalty starts, and that hair must not cross the limit itself.
PENALTY_MARGIN = 1e-3


@runtime_checkable
class Check(Protocol):
    """
    A requirement judged on a fit's result: name (one line) and status(params).

    status(params) -> {'constraint': name, 'value': text, 'satisfied': bool}; it may run
    the model and raise what the model raises (core.errors.MODEL_ERRORS).
    """

    name: str

    def status(self, params):
        """Whether it holds at params, with the value it judges (see the class)."""


@runtime_checkable
class Constraint(Check, Protocol):
    """
    A requirement the fit steers by: a Check with a penalty(params) residual.

    penalty(params) -> float: 0 while it holds, PENALTY_MARGIN inside its limit; beyond,
    about 1 per 1 % past the limit (100 per limit's worth), added to the target's
    residuals at every evaluation.
    """

    def penalty(self, params):
        """Return the residual it adds at params (see the class)."""


def judged(name, value, satisfied):
    """Return a requirement's status: its name, its value as text, whether it holds."""
    return {'constraint': name, 'value': value, 'satisfied': bool(satisfied)}


@dataclass(frozen=True)
class PilotFlowLimit:
    """Pilot flow (through bearings, damping orifice and rod clearance) at most maximum."""

    maximum: float  # [m^3/s]
    at_flow: float = REFERENCE_FLOW_STEP.initial_flow  # [m^3/s]

    @property
    def name(self):
        return (
            f'pilot flow at {self.at_flow / LITRE_PER_MINUTE:g} L/min <= '
            f'{self.maximum / LITRE_PER_MINUTE:g} L/min'
        )

    def value(self, params):
        """Pilot (poppet) flow [m^3/s] at the steady state of at_flow."""
        return float(flows(steady_state(params, self.at_flow), coefficients(params))[5])

    def penalty(self, params):
        """0 while it holds (with PENALTY_MARGIN); 1 per 1 % above the limit."""
        limit = self.maximum * (1.0 - PENALTY_MARGIN)
        return max(0.0, self.value(params) / limit - 1.0) * 100.0

    def status(self, params):
        """Whether it holds at params, with the value it judges, as the report shows it."""
        value = self.value(params)
        return judged(
            self.name, f'{value / LITRE_PER_MINUTE:.4f} L/min', value <= self.maximum * (1 + 1e-6)
        )


def _outside(value, low, high):
    """How far value lies outside [low, high], relative to the bound it passes [-]."""
    return max(0.0, low / value - 1.0 if value > 0.0 else math.inf, value / high - 1.0)


@dataclass(frozen=True)
class LandsInsideBore:
    """
    Both throttle lands lie inside the guide bore: D_1, D_2 <= d_p - 2 margin.

    margin [m]: the radial wall between the bore and a land's outer edge (docs/model.md).
    """

    margin: float  # [m]

    @property
    def name(self):
        return f'lands inside the bore: D_1, D_2 <= d_p - 2 x {self.margin * 1e3:g} mm'

    def value(self, params):
        """How far the outer land edge reaches beyond d_p - 2 margin [m] (<= 0 holds)."""
        limit = params['main_valve_back_diameter'] - 2.0 * self.margin
        return max(
            params['first_throttle_outer_diameter'], params['second_throttle_outer_diameter']
        ) - limit

    def penalty(self, params):
        """0 while it holds (with PENALTY_MARGIN); 1 per 1 % of the margin beyond."""
        return max(0.0, self.value(params) / self.margin + PENALTY_MARGIN) * 100.0

    def status(self, params):
        """Whether it holds at params, with the value it judges, as the report shows it."""
        value = self.value(params)
        return judged(
            self.name, f'outer land edge {-value * 1e3:.3f} mm inside that limit', value <= 0.0
        )


@dataclass(frozen=True)
class MainSpringRange:
    """
    The main spring is a soft one: rate k_m and preload force k_m x_0 within ranges.

    rate: (low, high) [N/m]; preload: (low, high) [N] (docs/model.md).
    """

    rate: tuple
    preload: tuple

    @property
    def name(self):
        return (
            f'main spring: k_m in [{self.rate[0] / 1e3:g}, {self.rate[1] / 1e3:g}] N/mm, '
            f'preload k_m x_0 in [{self.preload[0]:g}, {self.preload[1]:g}] N'
        )

    @staticmethod
    def values(params):
        """Return (rate [N/m], preload force [N])."""
        rate = params['main_spring_stiffness']
        return rate, rate * params['main_spring_preload']

    def penalty(self, params):
        """0 while both hold (with PENALTY_MARGIN); 1 per 1 % outside a range."""
        rate, preload = self.values(params)
        low, high = 1.0 + PENALTY_MARGIN, 1.0 - PENALTY_MARGIN
        return 100.0 * math.hypot(
            _outside(rate, self.rate[0] * low, self.rate[1] * high),
            _outside(preload, self.preload[0] * low, self.preload[1] * high),
        )

    def status(self, params):
        """Whether it holds at params, with the value it judges, as the report shows it."""
        rate, preload = self.values(params)
        return judged(
            self.name,
            f'k_m {rate / 1e3:.4g} N/mm, preload {preload:.4g} N',
            self.rate[0] <= rate <= self.rate[1] and self.preload[0] <= preload <= self.preload[1],
        )


@dataclass(frozen=True)
class ModesDecay:
    """
    Every linear mode of a case decays by e^-3 (95 %) within the measures' window.

    decay rate -Re lambda >= 3 / WINDOW, oscillatory or not, at the initial and final
    flows of the paper's test; the case is the parameter set scaled by changes with the
    preset held.
    A stability requirement, not a margin: a mode slower than this rings through
    the whole window of the measures.
    """

    label: str = 'table2'
    changes: dict = field(default_factory=lambda: dict(TABLE2_CHANGES))
    rate: float = 3.0 / WINDOW  # [1/s]

    @property
    def name(self):
        return f'{self.label}: every mode decays by 95 % within {WINDOW:g} s'

    def value(self, params):
        """Slowest decay rate -Re lambda [1/s] over every mode at both flows."""
        case = case_parameters(params, self.changes, 'held-preset', cracking_pressure(params))
        rates = [
            mode.decay_rate
            for flow in (REFERENCE_FLOW_STEP.initial_flow, REFERENCE_FLOW_STEP.final_flow)
            for mode in modes(case, flow)
        ]
        return min(rates)

    def penalty(self, params):
        """0 while it holds (with PENALTY_MARGIN); 1 per 1 % below the rate."""
        return max(0.0, 1.0 - self.value(params) / (self.rate * (1.0 + PENALTY_MARGIN))) * 100.0

    def status(self, params):
        """Whether it holds at params, with the value it judges, as the report shows it."""
        value = self.value(params)
        return judged(
            self.name,
            f'slowest decay {value:.3f} 1/s (needs {self.rate:g} 1/s)',
            value >= self.rate,
        )


RELIEF_TOLERANCE = 0.01  # p_s at the window's end within 1 % of the relieving steady state


def relief_error(params, flow_step=REFERENCE_FLOW_STEP, step_size=1e-5):
    """
    Return how far a step test ends from relieving through the main stage [-].

    The paper's test is run; the result is |p_s(end) / p_s,ss - 1|, p_s,ss the
    steady state at the final flow, where the main valve is open. A valve that
    ends with the main valve shut, or on another branch (the pilot poppet on its
    stop and p_s far above the preset), gets 1 or more.
    """
    final = steady_state(params, flow_step.final_flow)
    if final[X] <= 0.0:
        return 1.0
    waveforms = simulate(params, flow_step, step_size, 1e-3)
    settled = waveforms.time >= flow_step.end_time - 0.05
    if np.any(waveforms['main_valve_displacement'][settled] <= 0.0):
        return 1.0 + abs(float(np.mean(waveforms['supply_pressure'][settled])) / final[0] - 1.0)
    return abs(float(np.mean(waveforms['supply_pressure'][settled])) / final[0] - 1.0)


@dataclass(frozen=True)
class CaseRelieves:
    """
    A study case (preset held) ends its step test relieving through the main stage.

    changes: {symbol: percent}, e.g. {'d_c': -20}. The step test is run every
    evaluation, so name only the cases that bind; StudyRelieves checks them all.
    """

    changes: dict

    @property
    def name(self):
        label = ', '.join(f'{symbol} {percent:+g} %' for symbol, percent in self.changes.items())
        return f'{label}: the step test ends relieving through the main stage'

    def value(self, params):
        case = case_parameters(params, self.changes, 'held-preset', cracking_pressure(params))
        return relief_error(case)

    def penalty(self, params):
        """0 while p_s ends within 1 % of the relieving steady state; 1 per 1 % beyond."""
        return max(0.0, self.value(params) - RELIEF_TOLERANCE) * 100.0

    def status(self, params):
        """Whether it holds at params, with the value it judges, as the report shows it."""
        value = self.value(params)
        return judged(
            self.name,
            f'p_s at the end {value:.3%} from the relieving steady state',
            value <= RELIEF_TOLERANCE,
        )


@dataclass(frozen=True)
class StudyRelieves:
    """
    Every case of the paper's study (preset held) opens the main stage and relieves.

    Each case's step test must start with the main valve open and end within 1 % of
    the relieving steady state at the final flow (relief_error). The status also
    reports how far p_s before the step lies from the preset (the override from
    cracking to the initial flow).
    """

    name: str = 'every study case (preset held) opens the main stage and relieves'

    def failures(self, params):
        """Return ([what failed], largest relative p_s(initial flow) - preset)."""
        preset = cracking_pressure(params)
        failed, largest = [], 0.0
        for label, changes in study_cases():
            try:
                case = case_parameters(params, changes, 'held-preset', preset)
                initial = steady_state(case, REFERENCE_FLOW_STEP.initial_flow)
                error = relief_error(case)
            except MODEL_ERRORS as problem:
                failed.append(f'{label}: {problem}')
                continue
            if initial[X] <= 0.0:
                failed.append(f'{label}: main stage closed before the step')
            elif error > RELIEF_TOLERANCE:
                failed.append(f'{label}: ends {error:.1%} from the relieving steady state')
            largest = max(largest, abs(initial[0] / preset - 1.0))
        return failed, largest

    def status(self, params):
        """Whether it holds at params, with the value it judges, as the report shows it."""
        failed, largest = self.failures(params)
        passed = (
            f'all {len(study_cases())} cases; p_s before the step within {largest:.3%} '
            'of the preset'
        )
        return judged(self.name, '; '.join(failed) if failed else passed, not failed)
