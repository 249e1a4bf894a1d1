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

"""Benchmark valve_node's tick compute with every fault and sensor model active against none."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_faults.py [--ticks 20000] [--json FILE]
#
# The compute of one 1 kHz tick as valve_node does it, in this process, without DDS:
# advance the model 1 ms (100 RK4 steps of 10 us), check the fault schedule, run the
# sensor stage on the four pressures and fill the tick's CDR messages. Three valves
# are ticked in turn, tick by tick, in one run, so machine load hits them alike:
#   none:   the healthy valve with ideal sensors;
#   all:    every valve fault's term at once (bearing friction and stiction, damping and
#           bearing orifice blockage, weakened pilot spring, seat leakage, stuck main
#           valve, set after the start) and every sensor model on all four topics (lag,
#           bias, noise, quantisation, measuring range); stuck sensor and dropout are
#           left out: they skip work;
#   broken: all, plus a broken pilot spring. That valve relieves at 2.8 MPa with its
#           poppet wide open, a stiff state where the integrator splits each step
#           (integrator.splits_needed, shown): the cost of integrating that physical
#           state accurately, not of the fault terms.
# Reports per-tick compute p50, p90, p99 and mean of each, and the ratios to none.
# Target (issue 13): all <= 1.10 x none. On a loaded machine the p99 and the mean
# measure preemption (a descheduled tick costs milliseconds), the p50 the compute.

import argparse
import json
import time

import numpy as np
from valve_sim.core.integrator import splits_needed
from valve_sim.core.parameters import load_parameters
from valve_sim.core.realtime_model import NS_PER_S, RealTimeModel
from valve_sim.core.sensors import PRESSURE_NAMES
from valve_sim.recording.valve_topics import TickMessages
from valve_sim.ros.fault_injection import FaultInjection


FLOW = 5.0e-3 / 60.0  # [m^3/s] 5 L/min
PERIOD_NS = 1_000_000  # 1 kHz
WARM_UP = 200  # ticks per valve before measuring (compilation, caches)
AMBIENT = 101325.0  # [Pa]
ALL_FAULTS = {
    'fault.bearing_coulomb_friction': 5.0,
    'fault.bearing_static_friction': 8.0,
    'fault.damping_orifice_blockage': 0.1,
    'fault.bearing_orifice_blockage': 0.05,
    'fault.pilot_spring_weakening': 0.1,
    'fault.seat_leakage_diameter': 0.2e-3,
    'fault.main_valve_stuck': True,
}
ALL_SENSORS = {
    f'sensor.{topic}.{name}': value
    for topic in PRESSURE_NAMES
    for name, value in (
        ('bandwidth', 500.0),
        ('bias', 500.0),
        ('noise_std', 1000.0),
        ('resolution', 100.0),
        ('range_min', 1e5),
        ('range_max', 5e7),
    )
}


class TickingValve:
    """A valve ticked as valve_node ticks it: model, schedule, sensors, messages."""

    def __init__(self, params, faults, sensors):
        self.model = RealTimeModel(params, 1e-5, FLOW)
        self.model.start(0)
        self.model.retune(params, 1e-5, faults)  # faults from the healthy steady state on
        self.injection = FaultInjection(sensors)
        self.messages = TickMessages()
        self.durations_ns = []

    def tick(self):
        started = time.perf_counter_ns()
        now_ns = self.model.time_ns + PERIOD_NS
        self.model.advance_to(now_ns, FLOW, 50 * PERIOD_NS)
        self.injection.due(now_ns)
        self.injection.at_supply_limit(self.model.state, 0.0)
        readings = self.injection.readings(now_ns, self.model.state, AMBIENT)
        self.messages.fill(now_ns, self.model.state, FLOW, AMBIENT, readings)
        self.durations_ns.append(time.perf_counter_ns() - started)


def figures(durations_ns):
    us = np.asarray(durations_ns) / 1e3
    p50, p90, p99 = np.percentile(us, [50, 90, 99])
    return {
        'p50_us': p50,
        'p90_us': p90,
        'p99_us': p99,
        'mean_us': float(us.mean()),
        'ticks': len(us),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--ticks', type=int, default=20000, help='ticks per valve')
    parser.add_argument('--json', metavar='FILE', help='write the figures as JSON')
    args = parser.parse_args(argv)
    params = load_parameters().params
    valves = {
        'none': TickingValve(params, {}, {}),
        'all': TickingValve(params, ALL_FAULTS, ALL_SENSORS),
        'broken': TickingValve(
            params, {**ALL_FAULTS, 'fault.pilot_spring_broken': True}, ALL_SENSORS
        ),
    }
    for valve in valves.values():  # compile and warm up, not measured
        for _ in range(WARM_UP):
            valve.tick()
        valve.durations_ns.clear()
    for _ in range(args.ticks):
        for valve in valves.values():
            valve.tick()
    results = {name: figures(valve.durations_ns) for name, valve in valves.items()}
    for name, valve in valves.items():
        model = valve.model
        results[name]['splits'] = splits_needed(model.state, model._coefficients, 1e-5)
    for valve in ('all', 'broken'):
        for name in ('p50_us', 'p90_us', 'p99_us', 'mean_us'):
            results[valve][f'ratio_{name[:-3]}'] = results[valve][name] / results['none'][name]
    with open('/proc/loadavg') as stream:
        results['load_average'] = float(stream.read().split()[0])
    model_time = valves['all'].model.time_ns / NS_PER_S
    print(f'tick compute, {results["none"]["ticks"]} ticks each, the valves in turn:')
    print(
        f'{"":<8}{"p50 [us]":>10}{"p90 [us]":>10}{"p99 [us]":>10}{"mean [us]":>11}'
        f'{"splits":>8}'
    )
    for name in valves:
        r = results[name]
        print(
            f'{name:<8}{r["p50_us"]:>10.1f}{r["p90_us"]:>10.1f}{r["p99_us"]:>10.1f}'
            f'{r["mean_us"]:>11.1f}{r["splits"]:>8}'
        )
    for name in ('all', 'broken'):
        r = results[name]
        print(
            f'{name} / none: p50 {r["ratio_p50"]:.3f}, p90 {r["ratio_p90"]:.3f}, '
            f'p99 {r["ratio_p99"]:.3f}, mean {r["ratio_mean"]:.3f}'
            + (' (target <= 1.10)' if name == 'all' else ' (steps split: the state, see above)')
        )
    print(f'{model_time:.1f} s of model time each; load average {results["load_average"]:.1f}')
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(results, stream, indent=2)


if __name__ == '__main__':
    main()
