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
Steps in an inlet-flow signal: where they are, and when they took effect.

The six measures (measures.step_measures) need the time t_step of each step; this
module finds it, for the command line, the live analyser and bag analysis alike.

Dating a step (StepDetector, detect_steps, locate_step): where the flow is sampled
with every pressure sample (valve_node, the offline model), the step is dated at the
last sample with the old flow. A flowmeter sampled more coarsely than the pressure only
brackets it: between its last sample with the old flow and its first with the new
one (10 ms apart at 100 Hz). Inside that bracket the step is located from the
supply pressure, which a relief valve's step moves at once (the inlet flow
compresses the supply volume): at the point where the line through the first two
pressure samples outside the pre-step noise band meets the pre-step level, kept
between the last sample inside the band and the first outside. Its uncertainty is
half the pressure sample interval there.
"""

import math

import numpy as np


PRE_STEP_SPAN = 0.05  # [s] pressure before a bracketed step: its level and noise band
ONSET_BAND = 4.0  # a step moves p_s out of +-4 noise standard deviations of its level
ONSET_SAMPLES = 3  # ... for this many samples in a row (one noise spike is no step)


class StepDetector:
    """
    Finds steps in an inlet-flow signal, one sample at a time.

    A step is a change of more than `threshold` [m^3/s] from the current level;
    it is dated at the last sample before the change (where the model state was
    still computed with the old flow). Changes within `merge_time` [s] of a step
    belong to it (a ramp or a noisy edge), so they move the level but do not
    start a new step. Feed samples with update(); it returns a step or None.
    """

    def __init__(self, threshold=1e-6, merge_time=0.05):
        self.threshold = threshold
        self.merge_time = merge_time
        self.level = None
        self.previous_time = None
        self.last_step_time = -math.inf

    def update(self, time, flow):
        """Feed one sample; returns (t_step, flow_before, direction) when a step starts."""
        step = None
        if self.level is None:
            self.level = flow
        elif abs(flow - self.level) > self.threshold:
            if time - self.last_step_time > self.merge_time:
                step = (self.previous_time, self.level, 1 if flow > self.level else -1)
                self.last_step_time = self.previous_time
            self.level = flow
        self.previous_time = time
        return step


def noise_level(samples):
    """
    Return a robust estimate of the standard deviation of the noise on samples.

    From the differences of neighbouring samples, about their median (a ramp is no
    noise): 1.4826 times their median absolute deviation (the standard deviation of
    normal noise; a rare step barely moves it), over sqrt(2) (a difference holds the
    noise of two samples). 0 for fewer than 3 samples.
    """
    jumps = np.diff(np.asarray(samples, dtype=float))
    if len(jumps) < 2:
        return 0.0
    return 1.4826 * float(np.median(np.abs(jumps - np.median(jumps)))) / math.sqrt(2.0)


def locate_step(t, supply_pressure, bracket, direction):
    """
    Locate a step inside bracket (t_a, t_b) [s] from the supply pressure (module docstring).

    t [s] and supply_pressure [Pa]: the samples around the step, PRE_STEP_SPAN before
    t_a included; direction +1 up, -1 down. Returns (t_step, uncertainty) [s], or None
    when the pressure does not show the step (too few samples before it, or no sample
    leaves the noise band within twice the bracket).
    """
    t, p = np.asarray(t, dtype=float), np.asarray(supply_pressure, dtype=float)
    t_a, t_b = bracket
    before = (t >= t_a - PRE_STEP_SPAN) & (t <= t_a)
    if before.sum() < 3:
        return None
    level = float(np.median(p[before]))
    band = max(ONSET_BAND * noise_level(p[before]), 1e-7 * abs(level))
    e = direction * (p - level)
    outside = (e > band) & (t > t_a)
    runs = np.ones(max(len(e) - ONSET_SAMPLES + 1, 0), dtype=bool)
    for k in range(ONSET_SAMPLES):
        runs &= outside[k:len(e) - ONSET_SAMPLES + 1 + k]
    first = np.flatnonzero(runs & (t[:len(runs)] <= t_b + (t_b - t_a)))
    if len(first) == 0 or first[0] == 0:
        return None
    i = int(first[0])
    slope = (e[i + 1] - e[i]) / (t[i + 1] - t[i])
    onset = t[i] - e[i] / slope if slope > 0.0 else t[i - 1]
    t_step = min(max(onset, t[i - 1], t_a), t[i], t_b)  # between samples i - 1 and i
    below = t[t <= t_step]
    above = t[t > t_step]
    spacing = (above[0] if len(above) else t_step) - (below[-1] if len(below) else t_step)
    return t_step, spacing / 2.0


def detect_steps(t, inlet_flow, threshold=1e-6, merge_time=0.05):
    """All steps [(t_step, flow_before, direction)] of a sampled inlet flow [m^3/s]."""
    detector = StepDetector(threshold, merge_time)
    return [step for step in map(detector.update, t, inlet_flow) if step]
