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
What a calibration fits: FitParameters with their bounds, ties, and the values applied.

fit_parameters() checks the names and bounds a user gives (ROS names, paper symbols
or preset_pressure); step_time_parameters() adds the step times a recording located
between flow samples; fit_ties() makes a parameter follow a fitted one (d_v = 0.98
d_s); apply_values() turns fitted values into a validated parameter set, the
bearing coefficients K_1..K_3 re-derived when a bearing input moves (core.bearing)
and the preload re-solved for a held preset pressure.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
from typing import Optional

from valve_sim.core.bearing import with_bearing_fit
from valve_sim.core.errors import CalibrationError
from valve_sim.core.parameters import check_value, PRESET_PRESSURE, resolve_name, SPECS, validate
from valve_sim.core.steady_state import cracking_pressure, with_preset_pressure


@dataclass(frozen=True)
class FitParameter:
    """A fitted parameter: ROS name (or preset_pressure), bounds, unit and symbol."""

    name: str
    lower: float
    upper: float
    unit: str
    symbol: str
    start: Optional[float] = None  # the start value of a variable that is no model parameter


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


def fit_parameters(
    names: Sequence[str], bounds: Mapping[str, tuple[float, float]],
    params: Mapping[str, float],
) -> list[FitParameter]:
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
        start = start_value(params, name)
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


def start_value(params, name):
    """Return the value name starts from: in params, or the cracking pressure for a preset."""
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
