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
Parameter identification: fit chosen model parameters to step measures or to a recording.

One implementation for the paper's Figure 5 and for a rig's own valve:
- MeasuresTarget: the six step measures of the paper's test (value and tolerance each);
  residual = weight (model - value) / tolerance.
- RecordingTarget: a recorded step. The model is driven by the recorded inlet flow
  itself (core.simulation.simulate_recorded_flow) and compared with the recorded
  supply pressure, and with the main-valve position where it was recorded;
  residual = (model - recorded) / noise, the noise of each signal estimated from
  its sample-to-sample scatter before the first step.
Constraints add residuals that are zero while they hold (PilotFlowLimit,
ModesDecay, CaseRelieves, and the design rules LandsInsideBore and
MainSpringRange); checks (StudyRelieves) are too costly for every evaluation and
judge each start's result. Ties make a parameter follow a fitted one (d_v = 0.98 d_s,
the pilot seat a little under the rod); fitting the bearing orifice d_b re-derives the bearing
coefficients K_1..K_3 from it (core.bearing).
scipy.optimize.least_squares (trust region reflective,
bounds) runs from several starts; the best start that meets every constraint and
check wins. Approximate 95 % intervals and correlations come from the Jacobian at
the result: covariance s^2 (J^T J)^-1, s^2 = residual variance for a recording,
1 for measures (their residuals are in units of their tolerance).
"""

from dataclasses import dataclass, field
import math
import time as clock

import numpy as np
from scipy.optimize import least_squares
from valve_sim.analysis.measures import detect_steps, MEASURE_NAMES, step_measures, WINDOW
from valve_sim.analysis.paper import REFERENCE_SCENARIO, TABLE2_CHANGES
from valve_sim.analysis.study_cases import case_parameters, study_cases
from valve_sim.core.bearing import with_bearing_fit
from valve_sim.core.errors import CalibrationError, MODEL_ERRORS
from valve_sim.core.input_files import shown
from valve_sim.core.linear import modes
from valve_sim.core.model import coefficients, flows, X
from valve_sim.core.parameters import check_value, PRESET_PRESSURE, resolve_name, SPECS, validate
from valve_sim.core.simulation import LITRE_PER_MINUTE, simulate, simulate_recorded_flow
from valve_sim.core.steady_state import cracking_pressure, steady_state, with_preset_pressure


FAILED_RESIDUAL = 1e3  # every residual of a parameter set the model cannot run
UNDEFINED_MEASURE_RESIDUAL = 30.0  # a measure the model's response does not have
# Penalties turn on this far (relative) inside their limits: a least-squares optimum sits a
# hair beyond where a penalty starts, and that hair must not cross the limit itself.
PENALTY_MARGIN = 1e-3
FLAT_CHANGE = 1e-9  # relative residual change below which a parameter is flat
RANK_TOLERANCE = 1e-6  # singular values of the Jacobian below this (relative) count as 0
Z_95 = 1.959964  # two-sided 95 % quantile of the normal distribution


@dataclass(frozen=True)
class FitParameter:
    """A fitted parameter: ROS name (or preset_pressure), bounds, unit and symbol."""

    name: str
    lower: float
    upper: float
    unit: str
    symbol: str
    start: float = None  # the start value of a variable that is no model parameter


STEP_TIME = 'step_time_'  # fitted step times: step_time_1, step_time_2, ...


def step_time_parameters(target):
    """
    Return FitParameters of the step times a RecordingTarget located between flow samples.

    Each starts at its located time and stays inside its bracket; fitting them with the
    parameters makes the fit find where the steps lay, and its intervals include that
    uncertainty.
    """
    return [
        FitParameter(f'{STEP_TIME}{k}', low, high, 's', f't_step{k}', start)
        for k, (start, (low, high)) in enumerate(
            zip(getattr(target, 'step_times', ()), getattr(target, 'brackets', ())), start=1
        )
    ]


def fit_parameters(names, bounds, params):
    """
    Return the FitParameters for names (ROS names, paper symbols or preset_pressure).

    bounds: {name or symbol: (lower, upper)} overriding the spec limits. Raises
    CalibrationError when a name is unknown or repeated, or bounds are bad or
    exclude the start value (params, or the cracking pressure for preset_pressure).
    """
    chosen, overrides = [], {}
    for key, (lower, upper) in bounds.items():
        overrides[_resolve(key)] = (lower, upper)
    for raw in names:
        name = _resolve(raw)
        if name in [p.name for p in chosen]:
            raise CalibrationError(f"parameter '{name}' is named twice in --fit")
        spec = PRESET_PRESSURE if name == PRESET_PRESSURE.name else SPECS[name]
        lower, upper = overrides.pop(name, (spec.minimum, spec.maximum))
        for value in (lower, upper):
            check_value(name, value)
        if not lower < upper:
            raise CalibrationError(
                f"bounds of '{name}' ({spec.symbol}) must have LO < HI, got {lower:g}:{upper:g}"
            )
        start = _start_value(params, name)
        if not lower <= start <= upper:
            raise CalibrationError(
                f"bounds [{lower:g}, {upper:g}] {spec.unit} of '{name}' ({spec.symbol}) exclude "
                f'its start value {start:g} {spec.unit} (from the parameter file): '
                'widen them or start inside'
            )
        if start == 0.0:
            raise CalibrationError(
                f"'{name}' ({spec.symbol}) starts at 0; set a non-zero start value"
            )
        chosen.append(FitParameter(name, lower, upper, spec.unit, spec.symbol))
    if overrides:
        raise CalibrationError(
            f'--bounds names {", ".join(overrides)}, which --fit does not name'
        )
    if not chosen:
        raise CalibrationError('nothing to fit: name parameters with --fit')
    return chosen


def _resolve(name):
    name = name.strip()
    return name if name == PRESET_PRESSURE.name else resolve_name(name)


def _start_value(params, name):
    return cracking_pressure(params) if name == PRESET_PRESSURE.name else params[name]


# Parameters the bearing coefficients K_1..K_3 are fitted from (core.bearing): fitting
# one of them re-derives the coefficients, so Eq. (12) stays the fit of the bearing.
BEARING_INPUTS = (
    'bearing_orifice_diameter',
    'bearing_discharge_coefficient',
    'fluid_density',
    'fluid_viscosity',
)


def fit_ties(ties, fitted):
    """
    Return {tied name: (name it follows, factor)} from [(NAME, FACTOR, OTHER)].

    Names are ROS names or symbols. A tied parameter takes FACTOR times the value of
    the other at every evaluation (d_v = 0.98 d_s: the pilot seat a little under the
    rod). Raises CalibrationError when a tied parameter is fitted itself, tied twice,
    follows itself, or the factor is not a positive number.
    """
    fitted_names = {p.name for p in fitted}
    checked = {}
    for tied, factor, source in ties:
        tied, source = resolve_name(tied.strip()), resolve_name(source.strip())
        if tied in fitted_names or tied in checked or tied == source:
            raise CalibrationError(
                f'--tie {tied}={source}: a tied parameter must not be fitted, tied twice '
                'or tied to itself'
            )
        if not (math.isfinite(factor) and factor > 0.0):
            raise CalibrationError(f'--tie {tied}: the factor must be > 0, got {factor!r}')
        checked[tied] = (source, float(factor))
    return checked


def apply_values(params, fitted, values, preset_pressure=None, ties=None):
    """
    Return validated params with the fitted values set.

    ties {tied: (source, factor)} set factor times the source's value; a fitted or tied
    bearing input
    (BEARING_INPUTS) re-derives K_1..K_3. preset_pressure [Pa], if given (or
    fitted), re-solves the pilot spring preload last.
    """
    new = dict(params)
    for parameter, value in zip(fitted, values):
        if parameter.name.startswith(STEP_TIME):
            continue  # the target's (use_step_times), no parameter
        if parameter.name == PRESET_PRESSURE.name:
            preset_pressure = float(value)
        else:
            new[parameter.name] = float(value)
    for tied, (source, factor) in (ties or {}).items():
        new[tied] = factor * new[source]
    changed = {p.name for p in fitted} | set(ties or {})
    if changed & set(BEARING_INPUTS):
        new = with_bearing_fit(new)
    new = validate(new)
    if preset_pressure is not None:
        new = with_preset_pressure(new, preset_pressure)
    return new


# --- targets --------------------------------------------------------------------------------


class MeasuresTarget:
    """
    The six measures of the paper's step test (or a subset), each with value and tolerance.

    values, tolerances, weights: {measure name: number}; tolerance in the measure's unit.
    """

    kind = 'measures'

    def __init__(self, values, tolerances, weights=None, scenario=REFERENCE_SCENARIO,
                 step_size=1e-5):
        self.names = [name for name in MEASURE_NAMES if name in values]
        self.values = {name: float(values[name]) for name in self.names}
        self.tolerances = {name: float(tolerances[name]) for name in self.names}
        self.weights = {name: float((weights or {}).get(name, 1.0)) for name in self.names}
        self.scenario, self.step_size = scenario, step_size
        self.residual_names = list(self.names)

    @classmethod
    def from_document(cls, document, step_size=1e-5):
        """
        Build from {name: value} or {name: {"value", "tolerance", "weight"}} (JSON).

        A bare value gets a tolerance of 10 % of itself. Raises CalibrationError.
        """
        if not isinstance(document, dict):
            raise CalibrationError('a measures target must map measure names to values')
        values, tolerances, weights = {}, {}, {}
        unknown = sorted(set(document) - set(MEASURE_NAMES) - {'comment', 'source'})
        if unknown:
            raise CalibrationError(
                f'unknown measure(s) {", ".join(unknown)}; known: {", ".join(MEASURE_NAMES)}'
            )
        for name in MEASURE_NAMES:
            if name not in document:
                continue
            entry = document[name]
            entry = entry if isinstance(entry, dict) else {'value': entry}
            try:
                values[name] = float(entry['value'])
                tolerances[name] = float(entry.get('tolerance', 0.1 * abs(values[name])))
                weights[name] = float(entry.get('weight', 1.0))
            except (KeyError, TypeError, ValueError):
                raise CalibrationError(
                    f"measure {name}: need a number or {{'value': number, 'tolerance': number, "
                    f"'weight': number}}, got {shown(entry)}"
                ) from None
            numbers = (values[name], tolerances[name], weights[name])
            for what, number in zip(('value', 'tolerance', 'weight'), numbers):
                if not math.isfinite(number):
                    raise CalibrationError(f'measure {name}: {what} must be finite')
            if tolerances[name] <= 0.0 or weights[name] <= 0.0:
                raise CalibrationError(f'measure {name}: tolerance and weight must be > 0')
        if not values:
            raise CalibrationError('the measures target names none of ' + ', '.join(MEASURE_NAMES))
        return cls(values, tolerances, weights, step_size=step_size)

    def model_output(self, params):
        """Measures (StepMeasures.as_dict) and waveforms of the model's step test."""
        waveforms = simulate(params, self.scenario, self.step_size, 1e-4)
        measures = step_measures(
            waveforms.time,
            waveforms['supply_pressure'],
            waveforms['main_valve_displacement'],
            self.scenario.step_time,
        ).as_dict()
        return measures, waveforms

    def residuals(self, params):
        measures, _ = self.model_output(params)
        return np.array(
            [
                self.weights[name] * (measures[name] - self.values[name]) / self.tolerances[name]
                if measures[name] is not None
                else UNDEFINED_MEASURE_RESIDUAL
                for name in self.names
            ]
        )

    def covariance_scale(self, cost, count, fitted):
        """Residuals are in tolerance units: s^2 = 1."""
        return 1.0


def noise_level(signal, count):
    """
    Robust standard deviation [signal unit] of white noise on the first count samples.

    Differences with a non-finite end (a sample not recorded) are left out.
    """
    differences = np.diff(np.asarray(signal[:count], dtype=float))
    differences = differences[np.isfinite(differences)]
    if len(differences) < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(differences - np.median(differences))) / math.sqrt(2))


class RecordingTarget:
    """
    A recorded step: time [s], supply pressure [Pa gauge], inlet flow [m^3/s], main valve [m].

    main_valve may be None (a rig without a position sensor) or hold NaN where not
    recorded. inlet_flow[i] is the flow over the interval ending at time[i].
    step_times [s]: steps located between two flow samples (a flowmeter slower than the
    pressure, see measures.locate_step), brackets [(first, last)] [s] those samples'
    times: the recorded flow changes only at the sample at last, the model's at the step
    time. Located times are uncertain: step_time_parameters() fits them along with the
    parameters, inside their brackets.
    """

    kind = 'recording'

    def __init__(self, time, supply_pressure, inlet_flow, main_valve=None, step_size=1e-5,
                 step_threshold=1e-6, step_times=(), brackets=()):
        time = np.asarray(time, dtype=float)
        pressure = np.asarray(supply_pressure, dtype=float)
        flow = np.asarray(inlet_flow, dtype=float)
        if not (len(time) == len(pressure) == len(flow)) or len(time) < 10:
            raise CalibrationError('a recording needs at least 10 joined samples')
        if not (np.all(np.isfinite(pressure)) and np.all(np.isfinite(flow))):
            raise CalibrationError('the recording holds NaN or infinite pressure or flow samples')
        if np.any(np.diff(time) < step_size):
            raise CalibrationError(
                f'sample times must increase by at least the step size {step_size:g} s'
            )
        if np.any(flow < 0.0):
            raise CalibrationError('the recorded inlet flow is negative somewhere')
        self.steps = detect_steps(time, flow, step_threshold)
        if not self.steps:
            raise CalibrationError(
                f'no usable step: the recorded inlet flow stays within {step_threshold:g} m^3/s '
                f'of {flow[0]:g} m^3/s over {time[-1] - time[0]:.3f} s, so the recording shows '
                'no dynamics to fit (record a flow step)'
            )
        first_step = min([self.steps[0][0], *step_times])  # a located one can come earlier
        before = max(int(np.searchsorted(time, first_step, side='right')), 2)
        self.time, self.pressure, self.flow, self.step_size = time, pressure, flow, step_size
        self.step_times = list(step_times)  # located steps [s], fitted (step_time_parameters)
        self.brackets = list(brackets)  # [(first, last)] [s]: where each step time can lie
        self.pressure_noise = max(noise_level(pressure, before), 1.0)  # [Pa] floor: 1 Pa
        self.position = None
        self.residual_names = ['supply_pressure'] * len(time)
        if main_valve is not None:
            position = np.asarray(main_valve, dtype=float)
            if np.any(np.isinf(position)):
                raise CalibrationError('the recorded main-valve position is infinite somewhere')
            if np.any(np.isfinite(position)):
                self.position = position
                self.position_noise = max(noise_level(position, before), 1e-9)  # [m]
                recorded = np.isfinite(position)
                self.residual_names += ['main_valve'] * int(recorded.sum())

    def model_output(self, params):
        """Model states (rows) at the recorded sample times."""
        flow = self.flow.copy()
        for t_step, (_, last) in zip(self.step_times, self.brackets):
            after = min(int(np.searchsorted(self.time, last)), len(flow) - 1)
            flow[(self.time > t_step) & (self.time < last)] = flow[after]  # the new flow
        return simulate_recorded_flow(params, self.time, flow, self.step_size, self.step_times)

    def residuals(self, params):
        states = self.model_output(params)
        parts = [(states[:, 0] - self.pressure) / self.pressure_noise]
        if self.position is not None:
            recorded = np.isfinite(self.position)
            parts.append((states[recorded, X] - self.position[recorded]) / self.position_noise)
        return np.concatenate(parts)

    def covariance_scale(self, cost, count, fitted):
        """s^2: the residual variance, for noise levels that were only estimated."""
        return 2.0 * cost / max(count - fitted, 1)


# --- constraints and checks -----------------------------------------------------------------


@dataclass(frozen=True)
class PilotFlowLimit:
    """Pilot flow (through bearings, damping orifice and rod clearance) at most maximum."""

    maximum: float  # [m^3/s]
    at_flow: float = REFERENCE_SCENARIO.initial_flow  # [m^3/s]

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
        value = self.value(params)
        return {
            'constraint': self.name,
            'value': f'{value / LITRE_PER_MINUTE:.4f} L/min',
            'satisfied': value <= self.maximum * (1 + 1e-6),
        }


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
        value = self.value(params)
        return {
            'constraint': self.name,
            'value': f'outer land edge {-value * 1e3:.3f} mm inside that limit',
            'satisfied': bool(value <= 0.0),
        }


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
        rate, preload = self.values(params)
        return {
            'constraint': self.name,
            'value': f'k_m {rate / 1e3:.4g} N/mm, preload {preload:.4g} N',
            'satisfied': bool(self.rate[0] <= rate <= self.rate[1]
                              and self.preload[0] <= preload <= self.preload[1]),
        }


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
            for flow in (REFERENCE_SCENARIO.initial_flow, REFERENCE_SCENARIO.final_flow)
            for mode in modes(case, flow)
        ]
        return min(rates)

    def penalty(self, params):
        """0 while it holds (with PENALTY_MARGIN); 1 per 1 % below the rate."""
        return max(0.0, 1.0 - self.value(params) / (self.rate * (1.0 + PENALTY_MARGIN))) * 100.0

    def status(self, params):
        value = self.value(params)
        return {
            'constraint': self.name,
            'value': f'slowest decay {value:.3f} 1/s (needs {self.rate:g} 1/s)',
            'satisfied': bool(value >= self.rate),
        }


RELIEF_TOLERANCE = 0.01  # p_s at the window's end within 1 % of the relieving steady state


def relief_error(params, scenario=REFERENCE_SCENARIO, step_size=1e-5):
    """
    Return how far a step test ends from relieving through the main stage [-].

    The paper's test is run; the result is |p_s(end) / p_s,ss - 1|, p_s,ss the
    steady state at the final flow, where the main valve is open. A valve that
    ends with the main valve shut, or on another branch (the pilot poppet on its
    stop and p_s far above the preset), gets 1 or more.
    """
    final = steady_state(params, scenario.final_flow)
    if final[X] <= 0.0:
        return 1.0
    waveforms = simulate(params, scenario, step_size, 1e-3)
    settled = waveforms.time >= scenario.end_time - 0.05
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
        value = self.value(params)
        return {
            'constraint': self.name,
            'value': f'p_s at the end {value:.3%} from the relieving steady state',
            'satisfied': bool(value <= RELIEF_TOLERANCE),
        }


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
                initial = steady_state(case, REFERENCE_SCENARIO.initial_flow)
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
        failed, largest = self.failures(params)
        passed = (
            f'all {len(study_cases())} cases; p_s before the step within {largest:.3%} '
            'of the preset'
        )
        return {
            'constraint': self.name,
            'value': '; '.join(failed) if failed else passed,
            'satisfied': not failed,
        }


# --- the fit --------------------------------------------------------------------------------


@dataclass
class CalibrationResult:
    """What calibrate() found; values in SI, intervals approximate (Jacobian)."""

    parameters: dict
    fitted: list
    values: list
    start_values: list
    residuals: np.ndarray
    residual_names: list
    cost: float
    intervals: list = None  # [(low, high)] or None when not computed
    correlations: np.ndarray = None
    uncertainty_note: str = None  # why there are no intervals or correlations
    flat: list = field(default_factory=list)
    constraints: list = field(default_factory=list)
    starts: list = field(default_factory=list)
    evaluations: int = 0
    wall_time: float = 0.0
    interrupted: bool = False
    ties: dict = field(default_factory=dict)
    rank: int = None  # combinations of the fitted parameters the target determines

    @property
    def satisfied(self):
        return all(status['satisfied'] for status in self.constraints)


class _Objective:
    """Residuals of normalised values u = value / start; remembers the best evaluation."""

    def __init__(self, params, fitted, start, target, constraints, preset, progress, ties=None):
        self.params, self.fitted, self.start = params, fitted, np.asarray(start, dtype=float)
        self.ties = ties or {}
        self.target, self.constraints, self.preset = target, constraints, preset
        self.progress, self.count, self.best = progress, 0, (math.inf, None)
        self.size = None
        self.label, self.last_report = '', 0.0
        self.failure = None  # why the last failed evaluation failed

    def parameters(self, u):
        return apply_values(self.params, self.fitted, u * self.start, self.preset, self.ties)

    def use_step_times(self, u):
        """Hand the fitted step times of u to the target."""
        times = [v for p, v in zip(self.fitted, u * self.start) if p.name.startswith(STEP_TIME)]
        if times:
            self.target.step_times = times

    def __call__(self, u):
        self.count += 1
        self.use_step_times(u)
        try:
            params = self.parameters(u)
            residual = np.concatenate(
                [self.target.residuals(params), [c.penalty(params) for c in self.constraints]]
            )
        except MODEL_ERRORS as error:
            residual, self.failure = None, f'the model cannot run it: {error}'
        if self.size is None and residual is not None:
            self.size = len(residual)
        if residual is not None and not np.all(np.isfinite(residual)):
            residual, self.failure = None, _non_finite(self.target, residual)
        if residual is None:
            residual = np.full(self.size or 1, FAILED_RESIDUAL)
        cost = 0.5 * float(residual @ residual)
        if cost < self.best[0]:
            self.best = (cost, np.array(u, dtype=float))
        now = clock.monotonic()
        if self.progress and now - self.last_report >= 0.5:
            self.last_report = now
            self.progress(
                f'{self.label} evaluation {self.count}: cost {cost:.6g}, best {self.best[0]:.6g}'
            )
        return residual


def _non_finite(target, residual):
    """Say which residuals are not finite although the model ran: a problem of the data."""
    names = sorted({name for name, value in zip(target.residual_names, residual)
                    if not math.isfinite(value)})
    return (
        f'the residuals of {", ".join(names) or "the constraints"} are not finite although '
        'the model ran: the target holds NaN or infinite values, or a noise level that is '
        'not finite (a problem of the data, not of the model)'
    )


def _jacobian(objective, u, relative_step):
    """Central-difference Jacobian d(residual)/du at u, and the residual there."""
    base = objective(u)
    columns = []
    for j in range(len(u)):
        step = relative_step * max(abs(u[j]), 1e-3)
        up, down = u.copy(), u.copy()
        up[j] += step
        down[j] -= step
        columns.append((objective(up) - objective(down)) / (2.0 * step))
    return base, np.column_stack(columns)


def _starts(fitted, start, count, spread, seed):
    """Start points in normalised units: the file's values, then seeded log-normal ones."""
    rng = np.random.default_rng(seed)
    lower = np.array([p.lower for p in fitted]) / start
    upper = np.array([p.upper for p in fitted]) / start
    points = [np.ones(len(fitted))]
    for _ in range(count - 1):
        points.append(np.clip(np.exp(spread * rng.standard_normal(len(fitted))), lower, upper))
    return points, (lower, upper)


def calibrate(
    params,
    fitted,
    target,
    constraints=(),
    checks=(),
    preset_pressure=None,
    starts=3,
    spread=0.1,
    seed=0,
    tolerance=1e-10,
    diff_step=None,
    max_evaluations=2000,
    progress=None,
    ties=None,
):
    """
    Fit the FitParameters to target from several starts; returns a CalibrationResult.

    params: validated parameters (the fitted ones start at their values there);
    constraints: residual-adding constraints; checks: judged per start after its fit;
    preset_pressure [Pa]: held during the fit (the preload re-solved) unless fitted;
    starts: number of starts (the first is params itself), spread: log-normal
    standard deviation of the others, seed: their generator's seed; ties: {tied: (fitted
    parameter it follows, factor)} (fit_ties). Ctrl-C ends the
    fit: the result is then the best evaluation so far, marked interrupted.
    Raises CalibrationError for a flat (not identifiable) parameter or a start the
    model cannot run.
    """
    began = clock.monotonic()
    start = np.array(
        [p.start if p.start is not None else _start_value(params, p.name) for p in fitted]
    )
    objective = _Objective(
        params, fitted, start, target, constraints, preset_pressure, progress, ties
    )
    relative = diff_step or (1e-6 if target.kind == 'recording' else 1e-4)
    objective.label = 'identifiability check:'
    try:
        base, jacobian = _jacobian(objective, np.ones(len(fitted)), 0.01)
    except KeyboardInterrupt:
        if objective.best[1] is None:
            raise CalibrationError('interrupted before the first evaluation finished') from None
        cost, u = objective.best
        return _interrupted(params, fitted, start, target, constraints, objective, u, cost, began)
    if np.all(base == FAILED_RESIDUAL):
        if objective.failure.startswith('the model'):
            raise CalibrationError(
                'the model cannot run the target with the start values (no steady state or a '
                f'diverging run): check the parameter file and --params ({objective.failure})'
            )
        raise CalibrationError(f'the target cannot be compared: {objective.failure}')
    flat = [
        p
        for p, column in zip(fitted, jacobian.T)
        if np.linalg.norm(column) * 0.01 <= FLAT_CHANGE * (1.0 + np.linalg.norm(base))
    ]
    if flat:
        raise CalibrationError(
            'not identifiable from this target: '
            + ', '.join(f"'{p.name}' ({p.symbol})" for p in flat)
            + ' (moving it by 1 % changes no residual: the residual is flat in it); '
            'drop it from --fit'
        )
    points, bounds = _starts(fitted, start, max(1, starts), spread, seed)
    runs, interrupted = [], False
    for k, point in enumerate(points, start=1):
        objective.label = f'start {k}/{len(points)}'
        objective.best = (math.inf, None)
        try:
            if np.all(objective(point) == FAILED_RESIDUAL):
                runs.append({'start': list(point * start), 'values': None, 'cost': math.inf,
                             'message': 'skipped: the model cannot run at this start',
                             'checks': [], 'u': None})
                continue
            solution = least_squares(
                objective,
                point,
                bounds=bounds,
                method='trf',
                x_scale=1.0,
                diff_step=relative,
                ftol=tolerance,
                xtol=tolerance,
                gtol=tolerance,
                max_nfev=max_evaluations,
            )
            u, cost = solution.x, float(solution.cost)
            message = solution.message
        except KeyboardInterrupt:
            interrupted = True
            cost, u = objective.best
            message = 'interrupted (Ctrl-C): best evaluation so far'
        if u is None:
            break
        run = {'start': list(point * start), 'values': list(u * start), 'cost': cost,
               'message': message, 'u': u}
        try:
            result_params = objective.parameters(u)
            run['checks'] = [c.status(result_params) for c in (*constraints, *checks)]
        except MODEL_ERRORS as error:
            run['checks'] = [{'constraint': 'model runs', 'value': str(error),
                              'satisfied': False}]
        except KeyboardInterrupt:
            interrupted, run['checks'] = True, []
        runs.append(run)
        if progress:
            passed = all(check['satisfied'] for check in run['checks'])
            progress(
                f'{objective.label}: cost {cost:.6g} after {objective.count} evaluations, '
                f'constraints and checks {"met" if passed else "NOT met"}'
            )
        if interrupted:
            break
    if not runs:
        raise CalibrationError('interrupted before any evaluation finished')
    ran = [run for run in runs if run['u'] is not None]
    if not ran:
        raise CalibrationError('the model cannot run at any start: check the start values')
    feasible = [run for run in ran if all(c['satisfied'] for c in run['checks'])]
    best = min(feasible or ran, key=lambda run: run['cost'])
    u = best['u']
    result = CalibrationResult(
        parameters=objective.parameters(u),
        fitted=fitted,
        values=list(u * start),
        start_values=list(start),
        residuals=None,
        residual_names=list(target.residual_names) + [c.name for c in constraints],
        cost=best['cost'],
        constraints=best['checks'],
        starts=[{k: v for k, v in run.items() if k != 'u'} for run in runs],
        interrupted=interrupted,
        ties=dict(ties or {}),
    )
    if interrupted:
        result.residuals = objective(u)
    else:
        residual, jacobian = _jacobian(objective, u, max(relative, 1e-6))
        objective.use_step_times(u)  # the Jacobian moved them
        result.residuals = residual
        _uncertainty(result, target, jacobian, start)
    result.evaluations = objective.count
    result.wall_time = clock.monotonic() - began
    return result


def _interrupted(params, fitted, start, target, constraints, objective, u, cost, began):
    """Return the result of a fit stopped before its first start ran: the best so far."""
    return CalibrationResult(
        parameters=objective.parameters(u),
        fitted=fitted,
        values=list(u * start),
        start_values=list(start),
        residuals=objective(u),
        residual_names=list(target.residual_names) + [c.name for c in constraints],
        cost=cost,
        constraints=[],
        starts=[],
        evaluations=objective.count,
        wall_time=clock.monotonic() - began,
        interrupted=True,
    )


def _uncertainty(result, target, jacobian, start):
    """
    Approximate 95 % intervals and correlations from the Jacobian (normalised units).

    None of either when the Jacobian's rank (singular values above RANK_TOLERANCE of
    the largest) is below the number of fitted parameters: the target then pins only
    result.rank combinations of them (more parameters than measures), not each value.
    """
    count, fitted = len(result.residuals), len(result.fitted)
    singular = np.linalg.svd(jacobian, compute_uv=False)
    result.rank = int(np.sum(singular > RANK_TOLERANCE * singular[0])) if singular[0] > 0 else 0
    if result.rank < fitted:
        result.uncertainty_note = (
            f'no intervals: the target determines {result.rank} combinations of the '
            f'{fitted} fitted parameters, not each of them'
        )
        return
    scale = target.covariance_scale(result.cost, count, fitted)
    information = jacobian.T @ jacobian
    try:
        covariance = scale * np.linalg.inv(information)
    except np.linalg.LinAlgError:
        result.flat = [p.name for p in result.fitted]
        return
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    if not np.all(sigma > 0.0):
        result.uncertainty_note = (
            'no intervals or correlations: the residual is zero (a perfect fit, as of a '
            'noise-free recording of this very model), so the data tell nothing of their '
            'noise, and an uncertainty computed from them would be zero'
        )
        return
    result.intervals = [
        (value - Z_95 * s * scale_, value + Z_95 * s * scale_)
        for value, s, scale_ in zip(result.values, sigma, start)
    ]
    with np.errstate(invalid='ignore', divide='ignore'):
        result.correlations = covariance / np.outer(sigma, sigma)
