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
The valve across its operating envelope: every step or ramp must end where the physics says.

A run starts at the steady state of the initial flow (or from the empty, closed
valve for 0), changes the flow to the final one at STEP_TIME (at once or as a ramp)
and lasts until the valve has had time to fill V_s up to the preset and settle.
Its outcome:
  relieves        ends within 1 % of the steady state of the final flow, main stage open
                  (near the cracking flow it may still be approaching it slowly)
  pilot relieves  the same, with the main valve shut: the pilot passes the whole flow
  closed          final flow 0: the main valve shut, p_s not above the preset (the
                  poppet may still be closing: V_s drains through the pilot ever slower)
  stalled         ends anywhere else (another branch, still far from the steady state)
  diverged        the integration broke down (IntegrationError)
valve-sim's own measures say, with a reason, where a run has no step response.
"""

from dataclasses import dataclass
import math

import numpy as np
from valve_sim.analysis.steps.measures import step_measures
from valve_sim.core.errors import IntegrationError, SteadyStateError
from valve_sim.core.model import P_S, X
from valve_sim.core.simulation import FlowStep, simulate
from valve_sim.core.steady_state import steady_state, with_preset_pressure


STEP_TIME = 0.1  # [s]
SETTLE_TIME = 1.0  # [s] after the flow change (the measures' window)
END_TOLERANCE = 0.01  # p_s at the end within 1 % of the steady state
GOOD = ('relieves', 'pilot relieves', 'closed')


@dataclass
class EnvelopeRun:
    """One run of the envelope and what became of it (pressures gauge, Pa; flows m^3/s)."""

    preset_pressure: float
    initial_flow: float
    final_flow: float
    ramp_time: float
    outcome: str
    end_pressure: float = float('nan')
    steady_pressure: float = float('nan')
    measures: dict = None
    message: str = ''

    @property
    def good(self):
        return self.outcome in GOOD


def filling_time(params, preset_pressure, flow):
    """Time [s] the inlet flow needs to compress V_s from 0 to 1.2 x the preset."""
    return params['supply_volume'] / params['bulk_modulus'] * 1.2 * preset_pressure / flow


def envelope_run(params, preset_pressure, initial_flow, final_flow, ramp_time=0.0,
                 step_size=1e-5):
    """Run one case of the envelope with the preload set for preset_pressure [Pa]."""
    run = EnvelopeRun(preset_pressure, initial_flow, final_flow, ramp_time, 'stalled')
    case = with_preset_pressure(params, preset_pressure)
    fill = filling_time(case, preset_pressure, final_flow) if final_flow > 0.0 else 0.0
    end_time = STEP_TIME + ramp_time + SETTLE_TIME + (fill if initial_flow == 0.0 else 0.0)
    flow_step = FlowStep(initial_flow, final_flow, STEP_TIME, end_time, ramp_time)
    try:
        waveforms = simulate(case, flow_step, step_size, 1e-4)
    except IntegrationError as error:
        run.outcome, run.message = 'diverged', str(error)
        return run
    direction = 1 if final_flow >= initial_flow else -1
    run.measures = step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        STEP_TIME,
        direction,
    ).as_dict()
    settled = waveforms.time >= end_time - 0.05
    end = waveforms.states[-1]
    run.end_pressure = float(np.mean(waveforms.states[settled, P_S]))
    if final_flow == 0.0:
        if end[X] <= 0.0 and run.end_pressure <= 1.001 * preset_pressure:
            run.outcome = 'closed'
        else:
            run.message = 'flow stopped, but the valve did not close'
        return run
    try:
        steady = steady_state(case, final_flow)
    except SteadyStateError as error:
        run.message = str(error)
        return run
    run.steady_pressure = float(steady[P_S])
    error = abs(run.end_pressure / run.steady_pressure - 1.0)
    if error <= END_TOLERANCE:
        run.outcome = 'relieves' if end[X] > 0.0 else 'pilot relieves'
    else:
        run.message = (
            f'ends at p_s = {run.end_pressure:.6g} Pa, {error:.1%} from the steady state '
            f'{run.steady_pressure:.6g} Pa'
        )
    return run


# The envelope with faults and tank pressures, each run judged independently of the
# integrator's own checks (bench/bench_envelope.py, docs/benchmarks.md).
JUDGED = ('correct', 'refused', 'wrong')
AGREEMENT = 2e-3  # quarter-step agreement: share of burst_pressure (p_s) and of the inlet flow
BALANCE = 1e-2  # a steady end relieves the inlet flow within this share
STEADY_END = 1e-3  # a steady end: p_s spans less than this share of burst_pressure
# A start whose growing mode grows by more than exp(this) over the run: a step's own error
# (~1e-9 of a state) grows beyond AGREEMENT, so where it leaves the start is the step's.
UNSTABLE_GROWTH = math.log(AGREEMENT / 1e-9)
# Multiples of end_time a case is run to while its runs disagree and one is still moving.
RUN_ON = (1, 2, 4)
CYCLES = 0.5  # [s] a moving end is averaged over its whole cycles in this last stretch (_end)


@dataclass
class JudgedRun:
    """One run of the faulty envelope: its inputs, the verdict (JUDGED) and why."""

    case: dict
    verdict: str
    reason: str = ''
    ran_on: float = 0.0  # [s] the end the runs were judged at, if run on beyond end_time


def _end(waveforms, params, faults, tank, window=0.05, cycles=0.0):
    """
    Return (mean p_s [Pa], its span, mean relief [m^3/s]) over the run's last window [s].

    The relief is what the valve passes on average, the rate its stored volume grows
    (invariants.stored_volumes) added: a p_s still creeping up stores some inflow.
    cycles [s]: an end still moving (a span beyond STEADY_END, a hunting valve's limit
    cycle) is averaged over the whole cycles of p_s within this last stretch, between
    its first and last upward crossings of its mean, where there are two cycles or more:
    a window of a cycle and a bit weighs the cycle by where it happens to cut it.
    """
    from valve_sim.core.coefficients import coefficients
    from valve_sim.core.invariants import stored_volumes
    from valve_sim.core.model import relief_flows

    c = coefficients(params, faults)
    time, p_s = waveforms.time, waveforms.states[:, P_S]
    chosen = time >= time[-1] - window
    span = float(np.ptp(p_s[chosen]))
    if cycles and span > STEADY_END * params['burst_pressure']:
        chosen = _whole_cycles(time, p_s, cycles)
    last, time = waveforms.states[chosen], time[chosen]
    relief = np.mean([sum(relief_flows(state, c, tank)) for state in last])
    storing = np.sum(stored_volumes(last[-1], c) - stored_volumes(last[0], c)) / (
        time[-1] - time[0]
    )
    return float(np.mean(last[:, P_S])), span, float(relief + storing)


def _whole_cycles(time, p_s, stretch):
    """Return the samples of the whole p_s cycles in the last stretch [s] (or the stretch)."""
    within = np.flatnonzero(time >= time[-1] - stretch)
    above = p_s[within] >= np.mean(p_s[within])
    rises = within[1:][~above[:-1] & above[1:]]
    chosen = np.zeros(len(time), dtype=bool)
    if len(rises) >= 3:
        chosen[rises[0]:rises[-1] + 1] = True
    else:
        chosen[within] = True
    return chosen


def judged_run(params, faults, initial_flow, final_flow, initial_tank, final_tank,
               ramp_time=0.0, step_size=1e-5, end_time=1.0):
    """
    Run a faulty case at step_size and at a quarter of it; judge it independently.

    The flow and the tank pressure change at STEP_TIME (at once or over ramp_time).
    refused: the inputs or the start are refused before the run (ParameterError,
    SteadyStateError). correct: both runs end alike (or both reach burst_pressure, an
    overpressure) and, where the end is steady, it relieves the inlet flow and is the
    steady-state solver's state. Anything else is wrong. A case whose runs disagree at
    end_time while one of them is still moving is run on to RUN_ON times end_time and
    judged where both have settled (ran_on says how far): a transient whose timing is
    sensitive (a chattering, cavitating stretch) is compared where it ends, not mid-way.
    """
    case = {
        'faults': faults.describe() or 'healthy', 'initial_flow': initial_flow,
        'final_flow': final_flow, 'initial_tank': initial_tank, 'final_tank': final_tank,
        'ramp_time': ramp_time,
    }
    burst = params['burst_pressure']
    for factor in RUN_ON:
        ends = _quarter_step_ends(params, faults, initial_flow, final_flow, initial_tank,
                                  final_tank, ramp_time, step_size, end_time * factor)
        if isinstance(ends, tuple):
            verdict, reason = ends
            return JudgedRun(case, verdict, reason)
        if 'overpressure' in (ends[0][0], ends[1][0]):
            same = ends[0][0] == ends[1][0]
            return JudgedRun(case, 'correct' if same else 'wrong', 'overpressure' if same else
                             f'one step overpressured, the other not: {ends}')
        moving = max(ends[0][1], ends[1][1]) > STEADY_END * burst
        if _agree(ends, burst, final_flow) or not moving:
            break
    run = JudgedRun(case, 'correct', ran_on=end_time * factor if factor > 1 else 0.0)
    return _judged_ends(run, ends, params, faults, final_flow, final_tank)


def _quarter_step_ends(params, faults, initial_flow, final_flow, initial_tank, final_tank,
                       ramp_time, step_size, end_time):
    """Return the two runs' ends (_end, or ('overpressure', why)), or (verdict, reason)."""
    from valve_sim.core.errors import OverpressureError, ParameterError
    from valve_sim.core.simulation import TankPressure

    flow_step = FlowStep(initial_flow, final_flow, STEP_TIME, end_time, ramp_time)
    tank = TankPressure(initial_tank, final_tank, STEP_TIME, ramp_time)
    ends = []
    for step in (step_size, step_size / 4):
        try:
            run = simulate(params, flow_step, step, 1e-4, faults, tank=tank)
        except (ParameterError, SteadyStateError) as error:
            return 'refused', str(error)
        except OverpressureError as error:
            ends.append(('overpressure', str(error)))
            continue
        except IntegrationError as error:
            return 'wrong', f'step {step:g} s: {error}'
        ends.append(_end(run, params, faults, final_tank, cycles=CYCLES))
    return ends


def _agree(ends, burst, final_flow):
    """Tell whether the run and its quarter step end alike (AGREEMENT)."""
    (p_s, _, relief), (fine_p_s, _, fine_relief) = ends
    return abs(p_s - fine_p_s) <= AGREEMENT * burst and abs(relief - fine_relief) <= (
        AGREEMENT * max(final_flow, fine_relief, 1e-5)
    )


def _judged_ends(run, ends, params, faults, final_flow, final_tank):
    """Judge the two ends of a run that did not overpressure: run with its verdict."""
    def verdict(name, reason):
        ran_on = f'run on to {run.ran_on:g} s, moving and apart before: ' if run.ran_on else ''
        run.verdict, run.reason = name, ran_on + reason
        return run

    (p_s, span, relief), (fine_p_s, _, fine_relief) = ends
    burst = params['burst_pressure']
    if not _agree(ends, burst, final_flow):
        return verdict('wrong', f'quarter step disagrees: p_s {p_s:.6g} / {fine_p_s:.6g} Pa, '
                       f'relief {relief:.4g} / {fine_relief:.4g} m^3/s')
    if abs(relief - final_flow) > BALANCE * max(final_flow, 1e-5) and not (
        faults.main_valve_stuck
    ):
        end = 'steady end' if span <= STEADY_END * burst else 'moving end (whole cycles)'
        return verdict('wrong', f'{end} relieves {relief:.4g} of {final_flow:.4g}')
    if span > STEADY_END * burst or faults.main_valve_stuck:
        return verdict('correct', 'not steady at the end (or stuck): quarter step agrees, '
                       'the flow balance holds')
    if faults.bearing_static_friction or faults.bearing_coulomb_friction:
        # Friction holds the main valve anywhere in a band: no one steady state to solve for.
        return verdict('correct', 'friction: quarter step agrees, no unique steady state')
    try:
        solved = steady_state(params, final_flow, faults, final_tank)
    except SteadyStateError as error:
        return verdict('correct', f'no solver state to compare ({error})')
    if abs(solved[P_S] - p_s) > END_TOLERANCE * max(solved[P_S] - final_tank, 1e5):
        return verdict('wrong', f'steady end p_s {p_s:.6g} Pa, solver {solved[P_S]:.6g} Pa')
    return verdict('correct', 'agrees with a quarter step and the steady-state solver')


@dataclass
class PropertyReport:
    """
    What a run of the property campaign found (property_report).

    findings: defects (a divergence, non-finite states, other bytes twice, a quarter step
    ending elsewhere, an invariant alarm but cavitation's); alarms: the cavitation alarms,
    the model's vapour-cavity approximation in use (beyond Eqs. 1-16), not a defect;
    unstable_start: why the quarter step was not compared ('' where it was): a run that
    starts at an equilibrium with a mode growing by more than exp(UNSTABLE_GROWTH) over
    the run leaves it when its rounding says, so another step leaves it elsewhere (the
    envelope's judged_run refuses such a start).
    """

    findings: list
    alarms: list
    unstable_start: str = ''


def property_report(params, faults, initial_flow, final_flow, initial_tank, final_tank,
                    ramp_time=0.0, end_time=0.3, step_size=1e-5):
    """
    Return the PropertyReport of a case (test/core/test_properties.py, bench_properties.py).

    Refused inputs break nothing. The flow changes at STEP_TIME / 2. A run from an
    unstable start keeps its other checks: finite, deterministic, the invariants (the
    flow balance of its quasi-steady windows among them).
    """
    from valve_sim.core.coefficients import coefficients
    from valve_sim.core.errors import OverpressureError, ParameterError
    from valve_sim.core.simulation import simulate_alarms, TankPressure
    from valve_sim.core.stability import growing_mode

    flow_step = FlowStep(initial_flow, final_flow, STEP_TIME / 2, end_time, ramp_time)
    tank = TankPressure(initial_tank, final_tank, STEP_TIME / 2, ramp_time)
    runs = []
    for step in (step_size, step_size, step_size / 4):
        try:
            runs.append(simulate(params, flow_step, step, 1e-4, faults, tank=tank))
        except (ParameterError, SteadyStateError, OverpressureError):
            return PropertyReport([], [])
        except IntegrationError as error:
            return PropertyReport([f'diverged at step {step:g} s: {error}'], [])
    run, again, fine = runs
    findings = []
    if not np.all(np.isfinite(run.states)):
        findings.append('a state is not finite')
    if run.states.tobytes() != again.states.tobytes():
        findings.append('the same run twice gave other bytes')
    (p_s, _, relief), (fine_p_s, _, fine_relief) = (
        _end(w, params, faults, final_tank, 0.02) for w in (run, fine)
    )
    unstable = ''
    if initial_flow > 0.0:
        start = steady_state(params, initial_flow, faults, initial_tank, stable=False)
        growing = growing_mode(coefficients(params, faults), start, initial_flow, initial_tank)
        if growing is not None and growing.real * end_time > UNSTABLE_GROWTH:
            unstable = (f'starts at an unstable equilibrium (a mode grows at '
                        f'{growing.real:.3g} 1/s): the quarter step not compared')
    if not unstable and (abs(p_s - fine_p_s) > AGREEMENT * params['burst_pressure'] or abs(
        relief - fine_relief
    ) > AGREEMENT * max(final_flow, fine_relief, 1e-5)):
        findings.append(f'a quarter step ends elsewhere: p_s {p_s:.6g} / {fine_p_s:.6g} Pa, '
                        f'relief {relief:.4g} / {fine_relief:.4g} m^3/s')
    alarms = simulate_alarms(params, run, faults)
    findings += [str(alarm) for alarm in alarms if alarm.invariant != 'cavitation']
    return PropertyReport(
        findings, [str(alarm) for alarm in alarms if alarm.invariant == 'cavitation'], unstable
    )


def property_findings(params, faults, initial_flow, final_flow, initial_tank, final_tank,
                      ramp_time=0.0, end_time=0.3, step_size=1e-5):
    """Return the defects a case's run shows (property_report's findings), [] if none."""
    return property_report(params, faults, initial_flow, final_flow, initial_tank, final_tank,
                           ramp_time, end_time, step_size).findings
