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
valve_node's states tick by tick as arrays: one row per header stamp, every signal a column.

A bench scenario is judged on these (valve_sim.analysis.scenarios.expectations), and the test
kit hands them to a test. Rows are the ticks' stamps; a signal a tick did not publish
(a sensor in dropout) is NaN there. Pressures are the model's gauge pressures [Pa]
(the wire's absolute pressure minus ambient_pressure); time [s] counts from the
first tick (start_ns, the stamp of t = 0).
"""

from dataclasses import dataclass

import numpy as np
from valve_sim.analysis.steps.input_events import event_name
from valve_sim.analysis.steps.step_analysis import StepAnalysis
from valve_sim.core.quantities import FLOW, LENGTH, PRESSURE, VELOCITY


SIGNALS = {  # name: (dimension, symbol)
    'supply_pressure': (PRESSURE, 'p_s'),
    'intermediate_pressure': (PRESSURE, 'p_m'),
    'pilot_pressure': (PRESSURE, 'p_p'),
    'poppet_chamber_pressure': (PRESSURE, 'p_c'),
    'main_valve': (LENGTH, 'x'),
    'pilot_poppet': (LENGTH, 'y'),
    'main_valve_velocity': (VELOCITY, 'x_dot'),
    'pilot_poppet_velocity': (VELOCITY, 'y_dot'),
    'inlet_flow': (FLOW, 'q_in'),  # applied over the tick ending at the row's time
    'tank_pressure': (PRESSURE, 'p_t'),  # applied over that tick too (gauge)
    'relief_flow': (FLOW, 'q_r'),  # all the valve passes to the tank at the row's state
}


@dataclass
class TickSeries:
    """time [s] from the first tick, its stamps [ns], and a column per SIGNALS name."""

    time: np.ndarray
    stamps_ns: np.ndarray
    columns: dict

    @classmethod
    def from_rows(cls, rows, start_ns=None):
        """
        Build from {stamp_ns: {signal: value}}; start_ns: the stamp of t = 0 (default the first).

        Signals missing at a stamp are NaN.
        """
        stamps = np.array(sorted(rows), dtype=np.int64)
        start_ns = int(stamps[0]) if start_ns is None and stamps.size else (start_ns or 0)
        columns = {
            name: np.array([rows[stamp].get(name, np.nan) for stamp in stamps.tolist()], float)
            for name in SIGNALS
        }
        return cls((stamps - start_ns) / 1e9, stamps, columns)

    def __getitem__(self, name):
        return self.columns[name]

    def __len__(self):
        return len(self.time)

    def window(self, start=None, end=None):
        """Boolean mask of the rows with start <= time <= end [s] (None: open)."""
        mask = np.ones(len(self.time), bool)
        if start is not None:
            mask &= self.time >= start - 1e-12
        if end is not None:
            mask &= self.time <= end + 1e-12
        return mask

    def steps(self, threshold=1e-6, merge_time=0.05, events=()):
        """
        Return the step records of every inlet-flow step, times [s] from the first tick.

        The analyser's own StepAnalysis (analyser_node measures live with it), on
        these rows, the tank pressure included; events: (time [s], changes {name: value})
        of the faults and parameters changed, each from its time on, which end a step's
        window as any input change does (measure_windows). A step whose window runs past
        the end is measured on what there is.
        """
        analysis, records = StepAnalysis(threshold, merge_time), []
        for time, changes in events:
            analysis.add_event(time, event_name(changes))
        for row in zip(self.time, self['supply_pressure'], self['main_valve'],
                       self['inlet_flow'], self.time, self['tank_pressure']):
            records += analysis.add(*row)
        return records + analysis.finish()
