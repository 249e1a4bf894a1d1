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
The static pressure-flow characteristic of a relief valve from a slow flow ramp.

As a relief valve is tested on a rig (in the manner of ISO 6403): the inlet flow
q_in is ramped slowly from 0 up to a maximum and back down, and the supply
pressure p_s is plotted against q_in. Inputs are arrays over the samples: time
[s], p_s [Pa, gauge], q_in [m^3/s], and optionally the main-stage flow q_main
[m^3/s] (known in a simulation, usually not measured on a rig). The rising
ramp is the samples up to the first maximum of q_in, the falling ramp those
after its last maximum. Definitions (docs/characteristic.md):

- cracking pressure: p_s at which q_main first exceeds CRACKING_FRACTION (1 %)
  of the rated flow on the rising ramp (interpolated between samples);
- reseat pressure: p_s at which q_main first falls below that on the falling ramp;
- pressure at rated flow: p_s on the rising ramp where q_in reaches the rated flow;
- override: pressure at rated flow minus cracking pressure;
- hysteresis: the largest |p_s(rising) - p_s(falling)| at equal q_in between
  the cracking flow and the largest flow both ramps reached.

Without q_main (a rig's bag), cracking and reseat come from the curve itself:
the override line is the straight line fitted to the rising p_s(q_in) between
OVERRIDE_FIT (50 % and 100 %) of the rated flow; below the main stage's opening
the pilot stage alone passes the flow and the curve falls steeply away from that
line. Cracking is then p_s at the first rising sample from which the curve stays
within CURVE_BAND (0.1 %) of the pressure at rated flow of the line; reseat is
p_s at the last falling sample before the curve leaves that band.

ramp_test() runs the model's ramp and finds its marks both ways, steady_marks()
gives the exact steady state's, marks_table() shows them side by side.
"""

from dataclasses import asdict, dataclass, field

import numpy as np
from valve_sim.core.errors import ParameterError, SteadyStateError
from valve_sim.core.flow_step import LITRE_PER_MINUTE


CRACKING_FRACTION = 0.01  # main-stage flow threshold, fraction of the rated flow
OVERRIDE_FIT = (0.5, 1.0)  # rising flows (fractions of rated) the override line is fitted to
CURVE_BAND = 1e-3  # band around the override line, fraction of its pressure at rated flow
MAIN_FLOW_BASIS = 'main-stage flow'
CURVE_BASIS = 'pressure-flow curve (no main-stage flow given)'


@dataclass
class Characteristic:
    """Marks of a static characteristic, SI units; None values come with a reason."""

    rated_flow: float  # [m^3/s]
    basis: str  # how cracking and reseat were found: MAIN_FLOW_BASIS or CURVE_BASIS
    cracking_pressure: float = None  # [Pa]
    cracking_flow: float = None  # [m^3/s] q_in at cracking
    rated_pressure: float = None  # [Pa] p_s at rated flow, rising ramp
    override: float = None  # [Pa]
    reseat_pressure: float = None  # [Pa]
    reseat_flow: float = None  # [m^3/s] q_in at reseat
    hysteresis: float = None  # [Pa]
    hysteresis_flow: float = None  # [m^3/s] q_in where the hysteresis is largest
    reasons: dict = field(default_factory=dict)

    def as_dict(self):
        """JSON-ready dict of the marks."""
        return asdict(self)


def split_ramps(inlet_flow):
    """(rising, falling) index arrays: up to the first maximum of q_in, from its last one."""
    q = np.asarray(inlet_flow, dtype=float)
    top = np.flatnonzero(q == np.max(q))
    return np.arange(top[0] + 1), np.arange(top[-1], len(q))


def _crossing(values, level, upward):
    """
    Fractional index where values first cross level upward (or downward); None if never.

    A crossing needs a sample on the other side first: from <= level to > level
    (upward), or from >= level to < level (downward).
    """
    beyond = values > level if upward else values < level
    hits = np.flatnonzero(beyond[1:] & ~beyond[:-1]) + 1
    if len(hits) == 0:
        return None
    i = hits[0]
    a, b = values[i - 1], values[i]
    return i - 1 + (level - a) / (b - a) if b != a else float(i)


def _at(signal, position):
    """Interpolate signal at a fractional sample index."""
    return float(np.interp(position, np.arange(len(signal)), signal))


def override_line(inlet_flow, supply_pressure, rated_flow):
    """Fit p_s(q_in) on the rising ramp in OVERRIDE_FIT: (slope [Pa s/m^3], intercept [Pa])."""
    rising, _ = split_ramps(inlet_flow)
    q, p = inlet_flow[rising], supply_pressure[rising]
    inside = (q >= OVERRIDE_FIT[0] * rated_flow) & (q <= OVERRIDE_FIT[1] * rated_flow)
    if np.count_nonzero(inside) < 2:
        return None
    slope, intercept = np.polyfit(q[inside], p[inside], 1)
    return slope, intercept


def characteristic(supply_pressure, inlet_flow, rated_flow, main_flow=None):
    """
    Cracking, rated-flow and reseat pressures, override and hysteresis of a ramp.

    supply_pressure p_s [Pa], inlet_flow q_in [m^3/s], main_flow q_main [m^3/s]
    or None: arrays over the same samples of an up-and-down ramp. rated_flow
    [m^3/s] > 0. Returns a Characteristic; raises ParameterError for unusable input.
    """
    p = np.asarray(supply_pressure, dtype=float)
    q = np.asarray(inlet_flow, dtype=float)
    if not (np.isfinite(rated_flow) and rated_flow > 0.0):
        raise ParameterError(f'rated flow must be finite and > 0 m^3/s, got {rated_flow}')
    if p.shape != q.shape or p.ndim != 1 or len(p) < 3:
        raise ParameterError('supply pressure and inlet flow must be equal-length series of >= 3')
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise ParameterError('supply pressure and inlet flow must be finite')
    rising, falling = split_ramps(q)
    result = Characteristic(rated_flow, MAIN_FLOW_BASIS if main_flow is not None else CURVE_BASIS)
    reasons = result.reasons
    rated = _crossing(q[rising], rated_flow * (1.0 - 1e-12), upward=True)
    if rated is None:
        reasons['rated_pressure'] = (
            f'the ramp never reaches the rated flow {rated_flow:g} m^3/s (max {np.max(q):g})'
        )
    else:
        result.rated_pressure = _at(p[rising], rated)
    if main_flow is not None:
        m = np.asarray(main_flow, dtype=float)
        level = CRACKING_FRACTION * rated_flow
        crack = _crossing(m[rising], level, upward=True)
        reseat = _crossing(m[falling], level, upward=False) if len(falling) > 1 else None
    else:
        crack, reseat = _curve_marks(p, q, rising, falling, rated_flow, reasons)
    if crack is None:
        reasons.setdefault('cracking_pressure', 'the main stage does not open on the rising ramp')
    else:
        result.cracking_pressure = _at(p[rising], crack)
        result.cracking_flow = _at(q[rising], crack)
    if reseat is None:
        reasons.setdefault(
            'reseat_pressure',
            'the main stage does not close on the falling ramp (or was not open at its top)',
        )
    else:
        result.reseat_pressure = _at(p[falling], reseat)
        result.reseat_flow = _at(q[falling], reseat)
    if result.cracking_pressure is not None and result.rated_pressure is not None:
        result.override = result.rated_pressure - result.cracking_pressure
    else:
        reasons['override'] = 'needs both the cracking pressure and the pressure at rated flow'
    _hysteresis(p, q, rising, falling, result)
    return result


def _curve_marks(p, q, rising, falling, rated_flow, reasons):
    """Cracking and reseat sample positions from the override line (no main-stage flow)."""
    line = override_line(q, p, rated_flow)
    if line is None:
        reason = (
            'no main-stage flow, and too few rising samples between '
            f'{OVERRIDE_FIT[0]:.0%} and {OVERRIDE_FIT[1]:.0%} of the rated flow to fit '
            'the override line'
        )
        reasons['cracking_pressure'] = reasons['reseat_pressure'] = reason
        return None, None
    slope, intercept = line
    band = CURVE_BAND * abs(slope * rated_flow + intercept)

    def inside(indices):
        return np.abs(p[indices] - (slope * q[indices] + intercept)) <= band

    below_rated = np.flatnonzero(q[rising] <= rated_flow)
    portion = below_rated[-1] + 1 if len(below_rated) else 0
    outside = np.flatnonzero(~inside(rising[:portion]))
    crack = outside[-1] + 1 if len(outside) else 0
    left = np.flatnonzero(~inside(falling))
    reseat = left[0] - 1 if len(left) and left[0] > 0 else None
    return (float(crack) if crack < portion else None), (
        float(reseat) if reseat is not None else None
    )


def _hysteresis(p, q, rising, falling, result):
    """Largest |p_rising - p_falling| at equal flow, from cracking to the top of both ramps."""
    if result.cracking_flow is None or len(falling) < 2:
        result.reasons['hysteresis'] = 'needs the cracking flow and a falling ramp'
        return
    q_up, p_up = q[rising], p[rising]
    q_down, p_down = q[falling][::-1], p[falling][::-1]  # ascending flow, as interp wants
    top = min(np.max(q_up), np.max(q_down))
    low = max(result.cracking_flow, np.min(q_down))
    if top <= low:
        result.reasons['hysteresis'] = 'the ramps share no flow range above cracking'
        return
    grid = np.linspace(low, top, 400)
    # np.interp needs increasing abscissae: a real ramp may dither; keep the running maximum.
    up = _monotone_interp(grid, q_up, p_up)
    difference = np.abs(up - _monotone_interp(grid, q_down, p_down))
    k = int(np.argmax(difference))
    result.hysteresis, result.hysteresis_flow = float(difference[k]), float(grid[k])


def _monotone_interp(grid, flow, pressure):
    """Interpolate p at the grid flows along a ramp, on the samples where q sets a new maximum."""
    keep = np.concatenate([[True], flow[1:] > np.maximum.accumulate(flow)[:-1]])
    return np.interp(grid, flow[keep], pressure[keep])


def steady_marks(params, rated_flow, max_flow):
    """Return the steady state's cracking (lift-off, 1 % main-stage flow) and rated pressures."""
    from valve_sim.core.steady_curve import flow_for_main_stage_flow
    from valve_sim.core.steady_state import cracking_pressure, steady_state

    marks = {'lift_off_pressure': None, 'cracking_pressure': None, 'cracking_flow': None}
    try:
        marks['lift_off_pressure'] = cracking_pressure(params)
    except SteadyStateError as error:
        marks['lift_off_note'] = str(error)
    try:
        flow = flow_for_main_stage_flow(params, CRACKING_FRACTION * rated_flow, max_flow)
        marks['cracking_flow'] = flow
        marks['cracking_pressure'] = float(steady_state(params, flow)[0])
    except SteadyStateError as error:
        marks['cracking_note'] = str(error)
    marks['rated_pressure'] = float(steady_state(params, rated_flow)[0])
    if marks['cracking_pressure'] is not None:
        marks['override'] = marks['rated_pressure'] - marks['cracking_pressure']
    return marks


def ramp_test(params, max_flow, rated_flow, ramp_time, hold_time, step_size, record_interval):
    """Run the ramp; returns (Waveforms, main-stage flow per sample, {basis: Characteristic})."""
    from valve_sim.core.simulation import main_stage_flow, ramp_flows, run_flows

    waveforms = run_flows(
        params, ramp_flows(max_flow, ramp_time, hold_time, step_size), step_size, record_interval
    )
    main = main_stage_flow(params, waveforms.states)
    p_s, q_in = waveforms['supply_pressure'], waveforms.inlet_flow
    return waveforms, main, {
        'main_stage_flow': characteristic(p_s, q_in, rated_flow, main),
        'pressure_flow_curve': characteristic(p_s, q_in, rated_flow),
    }


def marks_table(marks, steady=None):
    """Return the marks in MPa and L/min as a table, beside the steady state's (a dict)."""
    lines = [
        f'{"mark":<22}{"ramp":>12}' + (f'{"steady state":>14}' if steady is not None else '')
    ]
    rows = (
        ('cracking [MPa]', 'cracking_pressure', 1e-6),
        ('cracking flow [L/min]', 'cracking_flow', 1 / LITRE_PER_MINUTE),
        ('rated-flow p [MPa]', 'rated_pressure', 1e-6),
        ('override [MPa]', 'override', 1e-6),
        ('reseat [MPa]', 'reseat_pressure', 1e-6),
        ('hysteresis [MPa]', 'hysteresis', 1e-6),
    )
    for label, key, scale in rows:
        value = getattr(marks, key)
        line = f'{label:<22}' + (f'{value * scale:12.5f}' if value is not None else f'{"-":>12}')
        if steady is not None:
            exact = steady.get(key)
            line += f'{exact * scale:14.5f}' if exact is not None else f'{"-":>14}'
        lines.append(line)
    lines += [f'  {name}: {reason}' for name, reason in marks.reasons.items()]
    return '\n'.join(lines)
