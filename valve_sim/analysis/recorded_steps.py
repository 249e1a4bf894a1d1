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
The steps of a recording: their measures, Figure 5 of each, and their report as text.

A recording is any object with the arrays of recording.signal_reader.Recording (time,
supply_pressure, main_valve, pilot_poppet, inlet_flow, inlet_flow_time, tank_pressure,
relief_flow; valve_pressure()): analyse() finds and measures every inlet-flow step
(step_analysis.StepAnalysis over its rows, as analyser_node does live), analyse_step()
one step at a given time. measures_table() is the six measures as text, beside the
paper's Figure 5 values for the paper's own run. sampling_problem() says whether the
samples of a live recording can carry a step's measures, measures_agree() whether two
analyses of one step agree (the demo checks its live measures so).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from valve_sim.analysis.paper import FIGURE5_MEASURES
from valve_sim.analysis.steps.measures import MEASURE_NAMES, step_measures, StepMeasures, WINDOW
from valve_sim.analysis.steps.sample_window import between, last_at_or_before
from valve_sim.analysis.steps.step_analysis import step_record, StepAnalysis, tank_details


PLOT_LEAD = (
    0.25  # [s] shown before the step, which the plot puts at 0.25 s as in the paper's Figure 5
)
# Live and offline measures come from the same code on the same samples; they may differ
# in the last bits when the analyser ran on another machine or NumPy build.
SAME_MEASURE_TOLERANCE = 1e-9  # relative
# [s] Sampling the measures need (docs/analyser.md, "The demo"). Each peak is refined by
# a parabola through the samples near it, so close to a peak (within T_d / 8) states may
# be at most PEAK_GAP_LIMIT apart, elsewhere in the window WINDOW_GAP_LIMIT (longer is
# also lag valve_node may have skipped: model time jumped, the state held). Offline at
# 1 kHz a 4 ms interval next to the first peak moves T_1 by 12 %; 3 ms intervals, and 10 ms
# ones away from the peaks, move no measure by more than a tenth of its test tolerance.
PEAK_GAP_LIMIT = 0.003
WINDOW_GAP_LIMIT = 0.01


def analyse(
    recording: Any, threshold: float = 1e-6, merge_time: float = 0.05
) -> list[dict[str, Any]]:
    """
    Step records of every step in a Recording (step_analysis.StepAnalysis over its rows).

    recording: a recording.signal_reader.Recording (Any: that wing is above this one).
    """
    analysis, records = StepAnalysis(threshold, merge_time), []
    for event in getattr(recording, 'events', None) or ():  # fault_status changes
        analysis.add_event(*event)
    flow_time = recording.time if recording.inlet_flow_time is None else recording.inlet_flow_time
    for row in zip(
        recording.time,
        recording.supply_pressure,
        recording.main_valve,
        recording.inlet_flow,
        flow_time,
        np.full(len(recording.time), np.nan)
        if recording.tank_pressure is None else recording.tank_pressure,
    ):
        records += analysis.add(*row)
    return records + analysis.finish()


def analyse_step(recording, t_step, direction):
    """Step record of a step at a given time t_step [s] (no detection)."""
    measures = step_measures(
        recording.time, recording.valve_pressure(), recording.main_valve, t_step, direction
    )
    if recording.tank_pressure is not None:
        measures.details.update(tank_details(recording.time, recording.tank_pressure, t_step))
    return step_record(t_step, None, direction, measures)


def plot_steps(path, recording, records, first_number=1):
    """
    Draw Figure 5 of each step.

    The figure goes to path itself for one step, and to path with _step<k> before
    the suffix for several. Titles give the step's number in the recording (the
    first record's is first_number) and its time from the first sample (a bag's
    own time axis is often the epoch).
    """
    from pathlib import Path

    from valve_sim.analysis.plotting import plot_step_response

    path, written = Path(path), []
    pressure = recording.valve_pressure()
    above_tank = recording.tank_pressure is not None and bool(
        np.any(np.isfinite(recording.tank_pressure))
    )
    for k, record in enumerate(records, start=first_number):
        target = path if len(records) == 1 else path.with_name(f'{path.stem}_step{k}{path.suffix}')
        t_step = record['t_step']
        shown = between(recording.time, t_step - PLOT_LEAD, t_step + WINDOW)
        flows = {
            name: flow[shown]
            for name, flow in (('inlet', recording.inlet_flow), ('relief', recording.relief_flow))
            if flow is not None and np.any(np.isfinite(flow[shown]))
        }
        plot_step_response(
            target,
            recording.time[shown] - t_step + PLOT_LEAD,
            pressure[shown],
            recording.main_valve[shown],
            recording.pilot_poppet[shown],
            PLOT_LEAD,
            record,
            title=(
                f'Recorded step {k}, {t_step - recording.time[0]:.4f} s after the first '
                f'sample, shown at {PLOT_LEAD:g} s'
            ),
            flows=flows if 'relief' in flows else None,
            pressure='p_s - p_t' if above_tank else 'p_s',
        )
        written.append(target)
    return written


def measures_table(measures, paper=False):
    """
    Return the six measures (a StepMeasures) as a table of lines; paper: beside Figure 5's.

    Only a run of the paper's own scenario should get the paper's column.
    """
    lines = [f'{"measure":<14}{"valve_sim":>12}' + (f'{"paper":>10}' if paper else '')]
    for name in MEASURE_NAMES:
        value = measures.values[name]
        shown = f'{value:12.4g}' if value is not None else f'{"-":>12}'
        lines.append(
            f'{name:<14}{shown}' + (f'{FIGURE5_MEASURES[name]:>10.4g}' if paper else '')
        )
    lines += [f'  {name}: {reason}' for name, reason in measures.reasons.items()]
    return '\n'.join(lines)


def steps_text(records, recording, first_number=1, paper=False):
    """
    Return each step's measures as a table (measures_table), with how each was found.

    Steps are numbered in the recording from first_number. paper: show the paper's
    values beside them, for the paper's own step on the reference valve only (the demo;
    a bag does not say which valve it recorded).
    """
    lines = []
    for k, record in enumerate(records, start=first_number):
        direction = 'up' if record['direction'] > 0 else 'down'
        lines.append(
            f'step {k}: {direction} at t = {record["t_step"]:.6f} s '
            f'({record["t_step"] - recording.time[0]:.4f} s after the first sample)'
        )
        lines.append(measures_table(
            StepMeasures({name: record[name] for name in MEASURE_NAMES}, record['reasons']),
            paper=paper,
        ))
        details = record['details']
        if details.get('t_step_bracket'):
            t_a, t_b = details['t_step_bracket']
            how = (
                'located from the supply pressure'
                if details['t_step_from'] == 'supply_pressure'
                else 'not visible in the supply pressure: dated at its last sample before '
                'the new flow'
            )
            lines.append(
                f'  step time: between flow samples {t_a - recording.time[0]:.4f} s and '
                f'{t_b - recording.time[0]:.4f} s ({(t_b - t_a) * 1e3:.3g} ms apart), {how}; '
                f'uncertainty +-{details["t_step_uncertainty_s"] * 1e3:.2g} ms'
            )
        if record['details'].get('T_s_from') == 'supply_pressure':
            lines.append(
                '  T_s_ms: from the supply pressure (main valve not recorded): the time after '
                'which |p_s - p_inf| stays below 5 % of p_1 - p_inf'
            )
        if 'note' in record['details']:
            lines.append(f'  note: {record["details"]["note"]}')
        if 'tank_pressure_pa' in details:
            lines.append(
                '  pressure: the supply above the tank; tank at '
                f'{details["tank_pressure_pa"]:.6g} Pa (gauge) at the step'
            )
        relief = flows_around(recording, record['t_step'])
        if relief:
            lines.append(
                '  flows [L/min] before the step / at the end of its window: inlet '
                f'{relief[0] * 6e4:.4g} / {relief[1] * 6e4:.4g}, relief (to the tank) '
                f'{relief[2] * 6e4:.4g} / {relief[3] * 6e4:.4g}'
            )
    return '\n'.join(lines)


def flows_around(recording, t_step):
    """
    (inlet, inlet, relief, relief) flow [m^3/s] just before t_step and at the window's end.

    None where the recording has no relief flow there.
    """
    if recording.relief_flow is None:
        return None
    before = last_at_or_before(recording.time, t_step)
    end = last_at_or_before(recording.time, t_step + WINDOW)
    values = (
        recording.inlet_flow[before], recording.inlet_flow[end],
        recording.relief_flow[before], recording.relief_flow[end],
    )
    return values if np.all(np.isfinite(values[2:])) else None


def sampling_problem(times, t_step, values):
    """
    Say why samples at times [s] cannot carry the measures of the step at t_step [s], or None.

    values: the step's measures, whose T_1 and T_d place its peaks (where those are
    undefined, every sample counts as next to a peak).
    """
    shown = times[between(times, t_step, t_step + WINDOW)]
    if shown.size < 2:
        return 'no samples in its window'
    t_1, t_d = values.get('T_1_ms'), values.get('T_d_ms')
    if t_1 is None or t_d is None:
        peaks, near = np.array([t_step]), WINDOW
    else:
        peaks, near = t_step + np.array([t_1, t_1 + t_d]) * 1e-3, t_d * 1e-3 / 8
    for start, end in zip(shown[:-1], shown[1:]):
        at_peak = np.any((start < peaks + near) & (end > peaks - near))
        limit = PEAK_GAP_LIMIT if at_peak else WINDOW_GAP_LIMIT
        if end - start > limit:
            return (
                f'a gap of {(end - start) * 1e3:.1f} ms between samples '
                f'{"next to a peak" if at_peak else "in its window"}, '
                f'{(start - t_step) * 1e3:.0f} ms after the step '
                f'(at most {limit * 1e3:g} ms there)'
            )
    return None


def measures_agree(first, second):
    """Return True if two steps' measures agree to SAME_MEASURE_TOLERANCE (undefined alike)."""
    for name in MEASURE_NAMES:
        a, b = first[name], second[name]
        if a is None or b is None:
            if a is not b:
                return False
        elif not math.isclose(a, b, rel_tol=SAME_MEASURE_TOLERANCE):
            return False
    return True
