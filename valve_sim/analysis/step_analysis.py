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

StepAnalysis is fed joined rows (valve_sim.analysis.signals) in time order: time t [s],
supply pressure p_s [Pa, gauge], main-valve displacement x [m] and applied inlet
flow q [m^3/s]. valve_sim.analysis.measures.StepDetector finds the steps (up and down, any
number); once a step's window (measures.WINDOW after it) is complete,
valve_sim.analysis.measures.step_measures gives its six measures. Only the rows from the
oldest open step on are kept, so memory stays bounded however long the stream.
The live analyser and `valve-sim analyse` both use this class, so a bag analysed
offline gives what the analyser computed while recording it.

Step records (the JSON file beside a bag, `valve-sim analyse --json`): t_step [s],
direction (+1 up, -1 down), flow_before [m^3/s], then the six measures
(None where undefined), 'reasons' and 'details' of measures.StepMeasures.as_dict().
"""

from collections import deque
import json
import os
from pathlib import Path

import numpy as np
from valve_sim.analysis.measures import step_measures, StepDetector, WINDOW
from valve_sim.analysis.signals import seconds
from valve_sim.core.output_files import json_text, replacing, write_text


def step_record(t_step, flow_before, direction, measures):
    """JSON-ready record of one step and its StepMeasures."""
    return {
        't_step': t_step,
        'direction': direction,
        'flow_before': flow_before,
        **measures.as_dict(),
    }


class StepAnalysis:
    """Detects the steps of a stream of rows and measures each on the window after it."""

    def __init__(self, threshold=1e-6, merge_time=0.05, window=WINDOW):
        self.threshold, self.merge_time, self.window = threshold, merge_time, window
        self._restart()

    def _restart(self):
        self.detector = StepDetector(self.threshold, self.merge_time)
        self.rows = deque()  # (t, p_s, x) from the oldest open step on
        self.open_steps = []  # (t_step, flow_before, direction) whose window is not complete

    def add(self, t, supply_pressure, main_valve, inlet_flow):
        """Feed one row; returns the records of the steps whose window it completes."""
        records = []
        if self.rows and t <= self.rows[-1][0]:
            records = self.finish()  # time went back (a new run): close the open steps
        step = self.detector.update(t, inlet_flow)
        if step:
            self.open_steps.append(step)
        self.rows.append((t, supply_pressure, main_valve))
        complete = [step for step in self.open_steps if t >= step[0] + self.window]
        for step in complete:
            self.open_steps.remove(step)
            records.append(self._measure(step))
        self._trim()
        return records

    def add_rows(self, rows):
        """
        Feed rows (time_ns, {role: value}) of signals.Joiner.

        Returns the records they complete.
        """
        return [
            record
            for time_ns, row in rows
            for record in self.add(
                seconds(time_ns), row['supply_pressure'], row['main_valve'], row['inlet_flow']
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
        Keep the rows from the oldest open step on.

        With none open, keep the last row (a next step's t_step).
        """
        oldest = min((step[0] for step in self.open_steps), default=self.rows[-1][0])
        while self.rows[0][0] < oldest:
            self.rows.popleft()

    def _measure(self, step):
        t_step, flow_before, direction = step
        t, p, x = np.array(self.rows, dtype=float).T
        return step_record(
            t_step, flow_before, direction, step_measures(t, p, x, t_step, direction, self.window)
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
