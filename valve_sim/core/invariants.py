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
What must hold in every run whatever its inputs, checked on the sampled states.

Four invariants (docs/model.md, "Invariants"), each judged from the samples alone,
independently of how the integrator got them:

- bounds: every state finite, every pressure within [PRESSURE_FLOOR, burst_pressure],
  each valve between its seat and its stroke;
- continuity: each chamber i stores what flows into it, over a window of samples
  Delta(p_i V_i / beta + its swept volume) = integral of its net inflow
  (Eqs. 1-4 integrated);
- flow balance: over a window in a steady state (inputs held, p_s steady) the valve
  relieves its inlet flow: integral(q_in - q_relief) = Delta(stored volume), the
  relief with the seat leakage;
- cavitation: no chamber's absolute pressure below the water's vapour pressure
  (model.VAPOUR_PRESSURE; Coefficients.cavitation_pressure, gauge): there the model
  holds the chamber near p_v with a vapour cavity (model.cavitation_share), an
  approximation beyond Eqs. 1-16, so the numbers that follow are the model's, not
  necessarily the real valve's.

Continuity and the balance are judged on quasi-steady windows (inputs held, p_s
within STEADY_SPAN of burst_pressure): there a correctly integrated run meets them
to the quadrature of its samples, and a numerical limit cycle (8.81 L/min relieved
of 5 L/min in) does not. A violation is an Alarm naming the invariant, its size
(relative to the window's throughput) and the time. run_alarms() checks a sampled
run; Monitor checks a live one sample by sample (valve_node, the FMU).
"""

from dataclasses import dataclass

import numpy as np
from valve_sim.core.faults import at_supply_limit
from valve_sim.core.limits import PRESSURE_FLOOR
from valve_sim.core.model import (
    cavity_volumes, flows, P_C, P_S, relief_flows, seat_leakage_flow,
    VAPOUR_PRESSURE, X, Y,
)

# A window: this many samples (10 ms at the default 0.1 ms record interval).
WINDOW_SAMPLES = 100
# Quasi-steady: p_s spans less than this share of burst_pressure over the window.
STEADY_SPAN = 1e-3
# Continuity and balance hold to this share of the window's throughput.
TOLERANCE = 0.02
# Below this flow [m^3/s] (0.006 L/min) a window's throughput is taken as this.
FLOW_FLOOR = 1e-7
INVARIANTS = ('bounds', 'continuity', 'flow balance', 'cavitation')
CHAMBERS = ('supply', 'intermediate', 'pilot', 'poppet')


@dataclass(frozen=True)
class Alarm:
    """A violated invariant: its name, its size (relative) and the time [s] it was seen."""

    invariant: str
    size: float
    time: float
    detail: str

    def __str__(self):
        return (
            f'invariant {self.invariant!r} violated at t = {self.time:.6g} s: '
            f'size {self.size:.3g} ({self.detail})'
        )

    def as_dict(self):
        """Return the alarm as a JSON-ready dict."""
        return {'invariant': self.invariant, 'size': self.size, 'time': self.time,
                'detail': self.detail}


def bounds_alarm(time, state, c):
    """Return the Alarm of a state outside its physical bounds, or None."""
    state = np.asarray(state, dtype=float)
    if not np.all(np.isfinite(state)):
        return Alarm('bounds', float('inf'), time, 'a state is not finite')
    pressures = state[P_S:P_C + 1]
    beyond = max(float(np.max(pressures)) - c.burst_pressure,
                 PRESSURE_FLOOR - float(np.min(pressures)), 0.0) / c.burst_pressure
    travel = max(-state[X], state[X] - c.main_valve_stroke, 0.0) / c.main_valve_stroke
    travel = max(travel, -state[Y] / c.poppet_stroke, state[Y] / c.poppet_stroke - 1.0)
    size = max(beyond, travel)
    if size > 0.0:
        return Alarm('bounds', float(size), time, 'a pressure or a valve beyond its limits')
    return None


def cavitation_alarm(time, state, c):
    """Return the Alarm of a chamber below the vapour pressure, or None (Coefficients c)."""
    pressures = np.asarray(state, dtype=float)[P_S:P_C + 1]
    lowest = int(np.argmin(pressures))
    below = c.cavitation_pressure - pressures[lowest]
    if not below > 0.0:  # a NaN is the bounds' alarm
        return None
    ambient = VAPOUR_PRESSURE - c.cavitation_pressure
    cavity = float(cavity_volumes(pressures, compliances(c), c.cavitation_pressure)[lowest])
    return Alarm(
        'cavitation', float(below / ambient), time,
        f'{CHAMBERS[lowest]} chamber at {pressures[lowest] + ambient:.4g} Pa absolute, '
        f'{below:.3g} Pa below the vapour pressure {VAPOUR_PRESSURE:g} Pa: a vapour cavity '
        f'of {cavity:.3g} m^3 (modelled: an approximation beyond Eqs. 1-16)',
    )


def compliances(c):
    """Return beta / V of the four chambers (s, m, p, c) [Pa/m^3] as an array."""
    return np.array([c.supply_compliance_inv, c.intermediate_compliance_inv,
                     c.pilot_compliance_inv, c.poppet_chamber_compliance_inv])


def stored_volumes(state, c):
    """
    Volume [m^3] each chamber holds, compressed and swept, up to a constant (Eqs. 1-4).

    The liquid's compression p V / beta (at most p_v's) less a vapour cavity
    (model.cavity_volumes): what the chamber stores with beta_eff, cavity and all.
    """
    pressures = np.asarray(state, dtype=float)[P_S:P_C + 1]
    inverse = compliances(c)
    liquid = np.maximum(pressures, c.cavitation_pressure) / inverse - cavity_volumes(
        pressures, inverse, c.cavitation_pressure)
    x, y = state[X], state[Y]
    return np.array([
        liquid[0] + c.supply_force_area * x + c.rod_area * y,
        liquid[1] + c.intermediate_force_area * x,
        liquid[2] - c.back_area * x,
        liquid[3] + c.poppet_chamber_area * y,
    ])


def sample_flows(state, inlet_flow, c, tank_pressure):
    """
    Return what a window needs of one sample, as one row.

    The net inflow [m^3/s] of each chamber (4), their throughputs (4), the relief flow
    and the chambers' stored volumes [m^3] (4).
    """
    q_m1, q_m2, q_n, q_c, q_s, q_p = flows(state, c, tank_pressure)
    q_l = seat_leakage_flow(state[P_S], c, tank_pressure) if c.seat_leakage_gain > 0.0 else 0.0
    return np.array([
        inlet_flow - q_m1 - q_n - q_s - q_l, q_m1 - q_m2, q_n - q_c, q_c + q_s - q_p,
        abs(inlet_flow) + abs(q_m1) + abs(q_n) + abs(q_s) + abs(q_l),
        abs(q_m1) + abs(q_m2), abs(q_n) + abs(q_c), abs(q_c) + abs(q_s) + abs(q_p),
        sum(relief_flows(state, c, tank_pressure)), *stored_volumes(state, c),
    ])


def window_alarms(time, pressures, inlet_flows, rows, c):
    """
    Return the Alarms of one window of samples.

    time [s]; pressures [Pa], rows of (p_s, p_m, p_p, p_c); inlet flows; sample_flows rows.
    inlet_flows[i] is the flow held over the interval ending at sample i, the same
    for all (a window starting at an input step would judge the step's first fast
    transient by its samples' quadrature); the coefficients c and the tank pressure
    are held throughout. Returns []
    for a window that is not quasi-steady (nothing is judged there); a chamber's
    continuity is judged only where its own pressure is quasi-steady too (a small
    chamber swinging fast between samples is beyond their quadrature).
    """
    supply_pressures = pressures[:, 0]
    if (
        len(time) < 3
        or np.ptp(supply_pressures) > STEADY_SPAN * c.burst_pressure
        or np.ptp(inlet_flows) > 0.0
        or at_supply_limit(float(np.max(supply_pressures)), c.supply_pressure_limit)
    ):
        return []
    net, through, relief, stored = rows[:, :4], rows[:, 4:8], rows[:, 8], rows[:, 9:]
    dt = np.diff(time)
    # The inlet flow is held over each interval; the others move with the state (trapezoids).
    net_in = np.sum(0.5 * (net[1:] + net[:-1]) * dt[:, None], axis=0)
    net_in[0] += np.sum((inlet_flows[1:] - 0.5 * (inlet_flows[1:] + inlet_flows[:-1])) * dt)
    volume = np.sum(0.5 * (through[1:] + through[:-1]) * dt[:, None], axis=0)
    duration = time[-1] - time[0]
    stored = stored[-1] - stored[0]
    alarms = []
    gaps = np.abs(net_in - stored) / np.maximum(volume, FLOW_FLOOR * duration)
    gaps[np.ptp(pressures, axis=0) > STEADY_SPAN * c.burst_pressure] = 0.0
    # Nor where its sampled net inflow swings (a poppet ringing between 1 ms ticks).
    gaps[np.ptp(net, axis=0) > TOLERANCE * np.mean(through, axis=0)] = 0.0
    worst = int(np.argmax(gaps))
    if gaps[worst] > TOLERANCE:
        alarms.append(Alarm('continuity', float(gaps[worst]), float(time[-1]),
                            f'{CHAMBERS[worst]} chamber over {duration:.3g} s'))
    inlet = float(np.sum(inlet_flows[1:] * dt))
    relieved = float(np.sum(0.5 * (relief[1:] + relief[:-1]) * dt))
    balance = abs(inlet - relieved - float(np.sum(stored)))
    scale = max(inlet, abs(relieved), FLOW_FLOOR * duration)
    steady = np.all(np.ptp(pressures, axis=0) <= STEADY_SPAN * c.burst_pressure)
    if steady and balance / scale > TOLERANCE:  # the relief moves with p_m and p_c
        alarms.append(Alarm(
            'flow balance', balance / scale, float(time[-1]),
            f'relief {relieved / duration * 6e4:.4g} L/min, inlet {inlet / duration * 6e4:.4g} '
            f'L/min over {duration:.3g} s at a steady p_s',
        ))
    return alarms


def run_alarms(time, states, inlet_flows, tank_pressures, segments, window=WINDOW_SAMPLES):
    """
    Return the Alarms of a sampled run (its first one per invariant and stretch).

    time, states, inlet_flows, tank_pressures: the samples (tank_pressures None: at
    ambient); segments: [(start time [s], Coefficients)] in force from that time on
    (a fault schedule's changes), the first at or before time[0]. Windows of window
    samples, none across a coefficient or tank-pressure change.
    """
    tank_pressures = np.zeros(len(time)) if tank_pressures is None else tank_pressures
    starts = [t for t, _ in segments]
    alarms, seen = [], set()
    segment = np.maximum(np.searchsorted(starts, time, side='right') - 1, 0)
    for start, c in segments:  # the sample-by-sample bounds, at array speed
        inside = segment == starts.index(start)
        pressures = states[:, P_S:P_C + 1]
        beyond = inside & ~(
            np.all(np.isfinite(states), axis=1)
            & np.all((pressures >= PRESSURE_FLOOR) & (pressures <= c.burst_pressure), axis=1)
            & (states[:, X] >= 0.0) & (states[:, X] <= c.main_valve_stroke)
            & (states[:, Y] >= 0.0) & (states[:, Y] <= c.poppet_stroke)
        )
        if np.any(beyond) and 'bounds' not in seen:
            i = int(np.argmax(beyond))
            alarms.append(bounds_alarm(float(time[i]), states[i], c))
            seen.add('bounds')
    c = segments[0][1]  # one ambient pressure, so one vapour pressure, for the whole run
    below = np.min(states[:, P_S:P_C + 1], axis=1) < c.cavitation_pressure
    if np.any(below):
        i = int(np.argmax(below))
        alarms.append(cavitation_alarm(float(time[i]), states[i], c))
    steady_span = STEADY_SPAN * min(c.burst_pressure for _, c in segments)
    for first in range(0, len(time) - window, window):
        part = slice(first, first + window + 1)
        index = segment[part]
        if (
            np.ptp(index) or np.ptp(tank_pressures[part])
            or np.ptp(states[part, P_S]) > steady_span or np.ptp(inlet_flows[part])
        ):
            continue  # not quasi-steady: nothing to judge, no flows to evaluate
        c, tank = segments[int(index[0])][1], float(tank_pressures[part][-1])
        rows = np.array([
            sample_flows(s, q, c, tank) for s, q in zip(states[part], inlet_flows[part])
        ])
        pressures = states[part, P_S:P_C + 1]
        for alarm in window_alarms(time[part], pressures, inlet_flows[part], rows, c):
            if alarm.invariant not in seen:
                alarms.append(alarm)
                seen.add(alarm.invariant)
    return alarms


class Monitor:
    """
    The invariants of a live run, sample by sample (a tick's state and inputs).

    observe() keeps the last window of samples and judges it when full; alarms counts
    every violation by invariant, last keeps the latest Alarm.
    """

    def __init__(self, window=WINDOW_SAMPLES):
        self.window = window
        self.samples = []
        self.alarms = dict.fromkeys(INVARIANTS, 0)
        self.last = None

    def restart(self):
        """Start a new window: the state jumped (a reset) or was held (a skipped lag)."""
        self.samples = []

    def observe(self, time, state, inlet_flow, tank_pressure, c):
        """
        Add a sample: time [s], state, the inlet flow held up to it, the tank pressure, c.

        Returns its new Alarms. A sample costs one evaluation of the flows, a full
        window a few sums.
        """
        found = []
        for alarm in (bounds_alarm(time, state, c), cavitation_alarm(time, state, c)):
            if alarm:
                found.append(alarm)
        previous = self.samples[-1] if self.samples else None
        if previous and (
            previous[2] != inlet_flow or previous[4] != tank_pressure or previous[5] is not c
        ):
            self.samples = []
        row = sample_flows(state, inlet_flow, c, tank_pressure)
        self.samples.append((time, state[P_S:P_C + 1], inlet_flow, row, tank_pressure, c))
        if len(self.samples) > self.window:
            found += window_alarms(
                np.array([s[0] for s in self.samples]),
                np.array([s[1] for s in self.samples]),
                np.array([s[2] for s in self.samples]),
                np.array([s[3] for s in self.samples]),
                c,
            )
            self.samples = self.samples[-1:]
        for alarm in found:
            self.alarms[alarm.invariant] += 1
            self.last = alarm
        return found
