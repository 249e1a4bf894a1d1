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
A bench scenario's inputs and events applied to a Lockstep, in pieces of any size.

The one implementation of a scenario's ticks on the lockstep protocol (ros.lockstep):
the scenario runner (ros.scenario_runner.drive) steps it from the first tick to the
last; valve_simulator (ros.simulation_server) in the pieces a simulation client asks
for (StepSimulation, SimulateSteps, playing). Each /clock step advances up to
ticks_per_clock ticks and never crosses a scenario step's start (batch_starts: an
event starts one); before it, the inlet flow of each of its ticks that changes is sent
stamped with the tick's start (and the tank pressure, when the scenario gives one: its
gauge value + ambient_pressure, as the topic is absolute); each event's parameter
changes are applied after the state of the tick it falls on. The lockstep makes the
states independent of how the ticks are grouped: a client's pieces give the scenario
runner's states, byte for byte. Past the scenario's end the inputs hold their last
values.
"""

import numpy as np

from valve_sim.core.errors import IncompleteRunError
from valve_sim.ros.clock_jumps import TICKS_PER_CLOCK
from valve_sim.ros.lockstep import NS_PER_S, START_NS


def batch_starts(ticks, breaks, size):
    """
    Return the first tick of each /clock step of a run of ticks ticks, steps of at most size.

    breaks: the ticks before which the driver acts between ticks (an event): a step
    starts at each, so none crosses one and every change lands on the tick it does
    with one tick per step.
    """
    bounds = [0, *sorted({tick for tick in breaks if 0 < tick < ticks}), ticks]
    return [tick for start, end in zip(bounds, bounds[1:]) for tick in range(start, end, size)]


def apply_event(driver, scenario, tick, changes):
    """Set an event's parameter changes after the state of tick; refused: IncompleteRunError."""
    try:
        driver.set_parameters(changes)
    except ValueError as error:
        raise IncompleteRunError(f'the event at {tick * scenario.period_ns / NS_PER_S:g} '
                                 f's: {error}') from None


def input_values(scenario):
    """Return the inlet flows [m^3/s] and tank pressures [Pa absolute] or None, a tick each."""
    flows = scenario.inputs['inlet_flow'].sample(scenario.tick_times())
    tank = scenario.inputs.get('tank_pressure')
    tanks = None if tank is None else tank.sample(scenario.tick_times()) + (
        scenario.ambient_pressure)  # [Pa absolute], as the topic takes it
    return flows, tanks


def change_ticks(values):
    """Return the ticks whose input value differs from the tick before's."""
    return (np.flatnonzero(values[1:] != values[:-1]) + 1).tolist()


class ScenarioStepper:
    """Steps a connected Lockstep through a BenchScenario: start(), then step(count) or batch()."""

    def __init__(self, scenario, driver, ticks_per_clock=TICKS_PER_CLOCK, flow_reply=None):
        if flow_reply is not None:
            ticks_per_clock = 1  # the controller answers each tick's state
        self.scenario, self.driver, self.ticks_per_clock = scenario, driver, ticks_per_clock
        self.flow_reply = flow_reply
        self.flows, self.tanks = input_values(scenario)  # flows: those sent, a tick each
        self.events = scenario.event_ticks()
        self.changes = {0, *change_ticks(self.flows),
                        *(() if self.tanks is None else change_ticks(self.tanks))}
        # where a /clock step may end: the scenario's steps (the runner's in one go), events
        self.bounds = sorted({*batch_starts(scenario.ticks, self.events, ticks_per_clock),
                              scenario.ticks, *self.events})
        self.tick = 0  # ticks done: the state at tick is the latest

    @property
    def time_ns(self):
        """Return the model time [ns] of the latest state."""
        return START_NS + self.tick * self.scenario.period_ns

    def start(self):
        """Send the first inputs, /clock at START_NS until the first state; tick 0's event."""
        self.driver.set_flow(self.flows[0], START_NS)
        if self.tanks is not None:
            self.driver.set_tank_pressure(self.tanks[0], START_NS)
        self.driver.start(START_NS, self.scenario.period_ns)
        self._after()

    def step(self, count):
        """Advance count ticks, in /clock steps of at most ticks_per_clock; return time_ns."""
        end = self.tick + count
        while self.tick < end:
            self.batch(end)
        return self.time_ns

    def batch(self, end):
        """Advance one /clock step towards tick end: its inputs, the step, an event after it."""
        tick, scenario, driver = self.tick, self.scenario, self.driver
        bound = next((b for b in self.bounds if b > tick), float('inf'))
        stop = min(end, bound, tick + self.ticks_per_clock)
        for change in sorted(self.changes.intersection(range(tick, stop))):
            stamp = START_NS + change * scenario.period_ns
            if self.flow_reply is None:
                driver.set_flow(self.flows[change], stamp)
            if self.tanks is not None:
                driver.set_tank_pressure(self.tanks[change], stamp)
        if self.flow_reply is not None and tick > 0:
            self.flows[tick] = self.flow_reply.reply(self.time_ns)
            driver.set_flow(self.flows[tick], self.time_ns)
        driver.tick(stop - tick)
        self.tick = stop
        self._after()

    def _after(self):
        """Apply the event of the tick just reached, if any (after its state)."""
        if self.tick in self.events:
            apply_event(self.driver, self.scenario, self.tick, self.events[self.tick])
