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
valve_node's ticks when /clock jumps forward by whole tick periods: one tick per period.

A lockstep driver (ros.lockstep) may advance /clock by several tick periods in one
message, which saves it a round trip per tick. rcl calls a timer once however many of
its periods passed, so valve_node's tick asks tick_times() which clock times to tick
at: for a jump of 2 to MAX_TICKS_PER_CLOCK whole periods on /clock's time, one per
period, each advancing the model by one period and publishing its state stamped with
its own time, the same messages that as many /clock messages one period apart give.
Any other call (the first, a jump back, a jump of another size, the system clock) is
one tick at the clock's time, with the catch-up and lag handling of a late tick.
The drivers step TICKS_PER_CLOCK periods at a time unless told otherwise.
"""

MAX_TICKS_PER_CLOCK = 100  # the largest jump [tick periods] ticked period by period
# The lockstep drivers' /clock step [tick periods]: a round trip per this many ticks, not
# per tick (a use_sim_time node of the user's that publishes once per tick needs 1).
# The largest: the same messages as 10, bit for bit, 1.2-1.7x as fast side by side
# (bench/bench_scenario.py's *_k100 kinds; docs/benchmarks.md, "Ticks per /clock").
TICKS_PER_CLOCK = MAX_TICKS_PER_CLOCK


def tick_times(previous_ns, now_ns, period_ns, sim_time):
    """
    Return the clock times [ns] to tick at, in order, when the clock reads now_ns [ns].

    previous_ns: the model time of the last tick [ns] (None before the first);
    period_ns: the tick period [ns]; sim_time: whether the clock is /clock's (ROS time).
    """
    if sim_time and previous_ns is not None:
        ticks, rest = divmod(now_ns - previous_ns, period_ns)
        if not rest and 2 <= ticks <= MAX_TICKS_PER_CLOCK:
            return range(previous_ns + period_ns, now_ns + 1, period_ns)
    return (now_ns,)
