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
The six measures of every inlet-flow step in a stream of samples, and their JSON file.

StepAnalysis is fed joined rows (valve_sim.analysis.steps.signals) in time order: time t [s],
supply pressure p_s [Pa, gauge], main-valve displacement x [m], applied inlet
flow q [m^3/s], the time [s] of the flow sample q came from and, where known, the
tank pressure p_t [Pa, gauge]. The measures are taken on the pressure across the
valve, p_s - p_t: the supply pressure above the tank, which is p_s itself with the
tank at ambient (a back pressure then moves no measure of the valve's own response).
valve_sim.analysis.steps.step_detection.StepDetector finds the steps (up and down, any
number); a step between two flow samples further apart than 1.5 pressure sample
intervals (a coarse flowmeter) is located inside them from the pressure
(step_detection.locate_step). A step's window ends measures.WINDOW after it, or at
the next change of any input first (measure_windows: the next flow step, a change
of p_t, an event given to add_event); once it has ended,
valve_sim.analysis.steps.measures.step_measures gives its six measures. Only the
rows from step_detection.PRE_STEP_SPAN before the oldest open step on are kept, so
memory stays bounded however long the stream.
The live analyser and `valve-sim analyse` both use this class, so a bag analysed
offline gives what the analyser computed while recording it.

Step records (the JSON file beside a bag, `valve-sim analyse --json`): t_step [s],
direction (+1 up, -1 down), flow_before and flow_after [m^3/s] (the flow at the end of
its window; `valve-sim calibrate --target-measures` simulates that step), the six measures
(None where undefined), 'reasons' and 'details' of measures.StepMeasures.as_dict().
A step between coarse flow samples adds to its details 't_step_bracket' [s, s] (those
samples), 't_step_from' ('supply_pressure' where located, else
'last_row_before_new_flow': the pressure did not show it) and 't_step_uncertainty_s'.
A step whose rows had the tank pressure adds 'pressure': 'supply above the tank' and
'tank_pressure_pa' [Pa, gauge], the tank's pressure at the step.
"""

from collections import deque
import json
import os
from pathlib import Path

import numpy as np
from valve_sim.analysis.steps.measure_windows import Cut, InputChanges
from valve_sim.analysis.steps.measures import step_measures, WINDOW
from valve_sim.analysis.steps.sample_window import last_at_or_before, TIME_TOLERANCE
from valve_sim.analysis.steps.signals import seconds
from valve_sim.analysis.steps.step_detection import locate_step, PRE_STEP_SPAN, StepDetector
from valve_sim.core.output_files import json_text, replacing, write_text


def step_record(t_step, flow_before, direction, measures, flow_after=None):
    """JSON-ready record of one step and its StepMeasures; flow_after: at its window's end."""
    return {
        't_step': t_step,
        'direction': direction,
        'flow_before': flow_before,
        'flow_after': flow_after,
        **measures.as_dict(),
    }


class StepAnalysis:
    """Detects the steps of a stream of rows and measures each on the window after it."""

    def __init__(self, threshold=1e-6, merge_time=0.05, window=WINDOW):
        self.threshold, self.merge_time, self.window = threshold, merge_time, window
        self.first_time = None  # [s] time of the first row fed: the recording's start
        self._restart()

    def _restart(self):
        self.detector = StepDetector(self.threshold, self.merge_time)
        self.changes = InputChanges(self.merge_time)  # the other inputs' changes, events
        # (t, p_s - p_t, x, p_t, q), PRE_STEP_SPAN before the oldest open step on
        self.rows = deque()
        self.open_steps = []  # (t_step, flow_before, direction) whose window is not complete
        self.brackets = {}  # t_step: (last flow sample before it, first after) [s]
        self.flow_time = None  # [s] time of the flow sample of the last row
        self.last_change = None  # the latest Cut: an open step's since
        self.since = {}  # t_step: the last change before it (a Cut)

    def add(self, t, supply_pressure, main_valve, inlet_flow, flow_time=None, tank_pressure=None):
        """
        Feed one row; returns the records of the steps whose window it completes.

        flow_time [s]: when the flow sample inlet_flow was taken (None: at t);
        tank_pressure [Pa, gauge]: the tank's pressure (None or nan: not known).
        """
        records = []
        self.first_time = t if self.first_time is None else self.first_time
        if self.rows and t <= self.rows[-1][0]:
            records = self.finish()  # time went back (a new run): close the open steps
        flow_time = t if flow_time is None else flow_time
        step, own = self.detector.update(t, inlet_flow), None
        cuts = self.changes.update(t, tank_pressure)
        if step:
            self.open_steps.append(step)
            if self.flow_time is not None:
                self.brackets[step[0]] = (self.flow_time, flow_time)
            edge = min(step[0], self.brackets.get(step[0], step)[0])  # the old flow's last
            own = Cut(edge, f'the inlet-flow step at {step[0]:.6f} s')
            self.since[step[0]] = self.last_change
            cuts.append(own)
        self.flow_time = flow_time
        known = tank_pressure is not None and tank_pressure == tank_pressure
        self.rows.append(
            (t, supply_pressure - tank_pressure if known else supply_pressure, main_valve,
             tank_pressure if known else np.nan, inlet_flow)
        )
        for cut in cuts:  # a change ends the window of every step before it (not its own)
            self.last_change = cut
            for cut_step in [open_step for open_step in self.open_steps
                             if not (open_step is step and cut is own)
                             and open_step[0] <= cut.time + TIME_TOLERANCE]:
                self.open_steps.remove(cut_step)
                records.append(self._measure(cut_step, cut))
        complete = [step for step in self.open_steps if t >= step[0] + self.window]
        for step in complete:
            self.open_steps.remove(step)
            records.append(self._measure(step))
        self._trim()
        return records

    def add_event(self, time, what):
        """Note a fault or parameter change that acts from time [s] on (what: its name)."""
        self.changes.add_event(time, what)

    def add_rows(self, rows):
        """
        Feed rows (time_ns, {role: value}) of signals.Joiner.

        Returns the records they complete.
        """
        return [
            record
            for time_ns, row in rows
            for record in self.add(
                seconds(time_ns),
                row['supply_pressure'],
                row['main_valve'],
                row['inlet_flow'],
                seconds(row['times'].get('inlet_flow', time_ns)),
                row.get('tank_pressure'),
            )
        ]

    def finish(self):
        """
        Return the records of the steps still open; then start over.

        Their window is truncated, as their details say.
        """
        records = [self._measure(step) for step in self.open_steps]
        self._restart()
        return records

    def _trim(self):
        """
        Keep the rows from PRE_STEP_SPAN before the oldest open step (or its bracket) on.

        With none open, keep PRE_STEP_SPAN before the last row (a next step's level).
        """
        oldest = min(
            (min(step[0], self.brackets.get(step[0], step)[0]) for step in self.open_steps),
            default=self.rows[-1][0],
        )
        while self.rows[0][0] < oldest - PRE_STEP_SPAN:
            self.rows.popleft()

    def _measure(self, step, cut=None):
        t_step, flow_before, direction = step
        t, p, x, tank, flow = np.array(self.rows, dtype=float).T
        bracket, timing = self.brackets.pop(t_step, None), {}
        if bracket and _coarser_than_rows(bracket, t):
            located = locate_step(t, p, bracket, direction)
            t_step = located[0] if located else t_step
            timing = {
                't_step_bracket': list(bracket),
                't_step_from': 'supply_pressure' if located else 'last_row_before_new_flow',
                't_step_uncertainty_s': located[1] if located else bracket[1] - bracket[0],
            }
        since = self.since.pop(step[0], None)
        measures = step_measures(t, p, x, t_step, direction, self.window, cut, since)
        measures.details.update(timing)
        measures.details.update(tank_details(t, tank, t_step))
        end = t_step + measures.details.get('window_s', 0.0)
        return step_record(t_step, flow_before, direction, measures,
                           float(flow[last_at_or_before(t, end)]))


def tank_details(time, tank_pressure, t_step):
    """
    Return the details a step's record gets from the tank's pressure, {} where it is not known.

    time [s], tank_pressure [Pa, gauge] (nan: not known) per row; t_step [s].
    """
    at_step = tank_pressure[max(int(np.searchsorted(time, t_step, side='right')) - 1, 0)]
    if at_step != at_step:
        return {}
    return {'pressure': 'supply above the tank', 'tank_pressure_pa': float(at_step)}


def _coarser_than_rows(bracket, t):
    """
    Whether flow samples bracket (t_a, t_b) [s] a stretch of pressure rows.

    That is: they are further apart than 1.5 row intervals and rows lie between them
    (a gap in a recording of valve_node, whose flow comes with every row, has none).
    """
    near = t[(t >= bracket[0] - PRE_STEP_SPAN) & (t <= bracket[1])]
    inside = np.count_nonzero((near > bracket[0]) & (near < bracket[1]))
    return (
        inside > 0
        and len(near) > 2
        and bracket[1] - bracket[0] > 1.5 * float(np.median(np.diff(near)))
    )


class MeasuresFile:
    """
    A bag's step records as one JSON document {"bag": name, "steps": [...]}, kept valid.

    Each append() writes a new file (the old one without its closing brackets, the new
    record, the brackets) and renames it over the old (core.output_files.replacing), so
    the file is valid JSON after every step, even when the disk fills during a write,
    and nothing but the file holds the records (memory stays bounded however many
    steps). Measures that are not finite are written as null (strict JSON).
    """

    TAIL = '\n]}\n'
    COPY_BLOCK = 1024 * 1024  # [bytes]

    def __init__(self, path, bag_name):
        self.path, self.count = Path(path), 0
        write_text(self.path, '{"bag": ' + json.dumps(bag_name) + ', "steps": [' + self.TAIL)

    def append(self, record):
        """Add one step record at the end of the steps list."""
        text = (',' if self.count else '') + '\n' + json_text(record) + self.TAIL
        with open(self.path, 'rb') as old, replacing(self.path, 'wb') as new:
            left = os.fstat(old.fileno()).st_size - len(self.TAIL)
            while left > 0:
                block = old.read(min(left, self.COPY_BLOCK))
                if not block:
                    break
                new.write(block)
                left -= len(block)
            new.write(text.encode())
        self.count += 1
