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
A bench scenario's inputs and events applied to a Lockstep as a client asks for ticks.

The scenario runner (ros.scenario_runner.drive) runs a scenario from its first tick to
its last in one go; ScenarioStepper runs the same ticks in the pieces a simulation
client asks for (ros.simulation_server: StepSimulation, SimulateSteps, playing): the
inlet flow (and tank pressure) of each tick published before it, each event's changes
applied after the state of the tick it falls on, a /clock step never crossing a tick
where the driver acts. The lockstep makes the states independent of how the ticks are
grouped, so they are the scenario runner's, byte for byte. Past the scenario's end the
inputs hold their last values.
"""

from valve_sim.ros.clock_jumps import TICKS_PER_CLOCK
from valve_sim.ros.lockstep import START_NS
from valve_sim.ros.scenario_runner import apply_event, change_ticks, FLOW_REPUBLISH, NS_PER_S


class ScenarioStepper:
    """Steps a connected Lockstep through a BenchScenario, count ticks at a time."""

    def __init__(self, scenario, driver):
        self.scenario, self.driver = scenario, driver
        times = scenario.tick_times()
        self.flows = scenario.inputs['inlet_flow'].sample(times)
        tank = scenario.inputs.get('tank_pressure')
        self.tanks = None if tank is None else tank.sample(times) + scenario.ambient_pressure
        self.events = scenario.event_ticks()
        self.republish = max(round(FLOW_REPUBLISH * NS_PER_S / scenario.period_ns), 1)
        breaks = {*self.events, *change_ticks(self.flows)}
        if self.tanks is not None:
            breaks.update(change_ticks(self.tanks))
        self.breaks = sorted(breaks)
        self.tick = 0  # ticks done: the state at tick is the latest

    @property
    def time_ns(self):
        """Return the model time [ns] of the latest state."""
        return START_NS + self.tick * self.scenario.period_ns

    def start(self):
        """Publish the first inputs and /clock at START_NS; wait for the first state."""
        self.driver.set_flow(self.flows[0])
        if self.tanks is not None:
            self.driver.set_tank_pressure(self.tanks[0], START_NS)
        self.driver.start(START_NS, self.scenario.period_ns)

    def step(self, count, ticks_per_clock=TICKS_PER_CLOCK):
        """Advance count ticks (in /clock steps of at most ticks_per_clock); return time_ns."""
        end = self.tick + count
        while self.tick < end:
            self._before(self.tick)
            size = min(end, self.tick + ticks_per_clock, self._next_break(self.tick)) - self.tick
            self.driver.tick(size)
            self.tick += size
        return self.time_ns

    def _next_break(self, tick):
        """Return the next tick after tick at which the driver acts (inf: none)."""
        following = (b for b in self.breaks if b > tick)
        republish = (tick // self.republish + 1) * self.republish
        return min(next(following, float('inf')), republish)

    def _before(self, tick):
        """Apply what acts before the tick from tick: an event, a new or republished input."""
        scenario, driver = self.scenario, self.driver
        if tick in self.events:
            apply_event(driver, scenario, tick, self.events[tick])
        index = min(tick, scenario.ticks)
        if self.flows[index] != driver.flow or tick % self.republish == 0:
            driver.set_flow(self.flows[index])
        if self.tanks is not None and (self.tanks[index] != driver.tank
                                       or tick % self.republish == 0):
            driver.set_tank_pressure(self.tanks[index], driver.clock_ns)
