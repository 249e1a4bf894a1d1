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
Which samples of a series lie in an analysis window: its edges, to within TIME_TOLERANCE.

Series are timed two ways: header stamps in ns / 1e9 (the node, a bag) and k *
step_size (the offline model). Their times of one instant differ in the last bits, so
a sample exactly on a window's edge was in one series and not in the other (P_o 2e-3
apart, p_inf a mean of 51 samples against 50). A sample within TIME_TOLERANCE of an
edge is on it: far below any sample interval (10 us or more) and above the rounding of
epoch times (1.8e9 s: 0.24 us).
"""

import numpy as np


TIME_TOLERANCE = 1e-6  # [s]


def last_at_or_before(t, time):
    """Return the index of the last sample of t [s] at or before time [s] (0 if none)."""
    return max(int(np.searchsorted(t, time + TIME_TOLERANCE, side='right')) - 1, 0)


def window_end(t, t_step, window):
    """
    Return (end [s], full): where the window after t_step [s] ends in the samples t [s].

    full: the samples reach t_step + window (to within TIME_TOLERANCE), the end; else
    the window is truncated at the last sample.
    """
    full = bool(t[-1] >= t_step + window - TIME_TOLERANCE)
    return (t_step + window if full else float(t[-1])), full


def between(t, start, end):
    """Return the mask of the samples t [s] from start to end [s], both edges in."""
    return (t >= start - TIME_TOLERANCE) & (t <= end + TIME_TOLERANCE)


def last_span(t, end, span):
    """Return the mask of the samples t [s] in the span [s] before end [s], its edges in."""
    return t >= end - span - TIME_TOLERANCE
