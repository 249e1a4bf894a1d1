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

"""Envelope sweep: presets, flows, steps and ramps; then every fault and tank pressure, judged."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_envelope.py [--json FILE] [--faults-only]
#
# Every ordered pair of distinct flows of FLOWS (0 = the empty, closed valve as
# start, or the flow stopped as end) at every preset of PRESETS, as a step and as a
# RAMP_TIME ramp: valve_sim.analysis.steps.envelope judges each run (relieves, pilot
# relieves, closed, stalled, diverged). The test suite runs a coarse subset
# (test/analysis/test_envelope.py); this is the full grid. Exit code 1 if any run stalled
# or diverged.
#
# Then the faulty envelope (issue 40): every fault at several severities (FAULTS), flows
# held, stepped and ramped (FLOW_CHANGES), tank pressures held, stepped and ramped up to
# burst_pressure (TANK_CHANGES). valve_sim.analysis.steps.envelope.judged_run judges each run
# independently of the run's own checks (the same run at a quarter of the step, the
# steady-state solver and the flow balance for a steady end) as correct, refused before
# the run, or wrong; the counts are printed, every wrong run with its reason. Exit code 1
# if any run is wrong. test/analysis/test_envelope.py runs a sample.

import argparse
from collections import Counter
import json
import sys
import time

from valve_sim.analysis.steps.envelope import envelope_run, judged_run
from valve_sim.core.faults import HEALTHY
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import LITRE_PER_MINUTE


PRESETS = (3e6, 4e6, 5e6, 7e6, 8.5e6, 10e6)  # [Pa]
FLOWS = (0.0, 1.0, 5.0, 10.0, 15.0, 20.0, 25.0)  # [L/min]
RAMP_TIME = 0.1  # [s]
L = LITRE_PER_MINUTE
FAULTS = [{}] + [
    {f'fault.{name}': value for name in names}
    for names, values in (
        (('bearing_coulomb_friction', 'bearing_static_friction'), (50.0, 200.0, 1000.0)),
        (('damping_orifice_blockage',), (0.5, 0.85, 1.0)),
        (('bearing_orifice_blockage',), (0.5, 0.9, 1.0)),
        (('pilot_spring_weakening',), (0.5, 0.95, 1.0)),
        (('seat_leakage_diameter',), (0.5e-3, 2e-3, 5e-3)),
    )
    for value in values
] + [{'fault.pilot_spring_broken': True}, {'fault.main_valve_stuck': True}]
# (initial, final) inlet flow [m^3/s], ramp time [s]
FLOW_CHANGES = ((5 * L, 5 * L, 0.0), (5 * L, 20 * L, 0.0), (20 * L, 3 * L, 0.05))
# (initial, final) tank pressure [Pa, gauge], ramp time [s]; burst_pressure is 35 MPa
TANK_CHANGES = ((0.0, 0.0, 0.0), (0.0, 10e6, 0.0), (0.0, 10e6, 0.05), (0.0, 34e6, 0.0),
                (10e6, 0.0, 0.0))


def faulty_cases():
    """Yield judged_run's keyword arguments for every case of the faulty envelope."""
    for changes in FAULTS:
        for initial, final, flow_ramp in FLOW_CHANGES:
            for tank_initial, tank_final, tank_ramp in TANK_CHANGES:
                yield {
                    'faults': HEALTHY.changed(changes), 'initial_flow': initial,
                    'final_flow': final, 'initial_tank': tank_initial,
                    'final_tank': tank_final, 'ramp_time': max(flow_ramp, tank_ramp),
                }


def case_text(case):
    """Return a faulty case as text: its faults, flows [L/min] and tank pressures [MPa]."""
    return (
        f"{case['faults'].describe()}, {case['initial_flow'] / L:g} -> "
        f"{case['final_flow'] / L:g} L/min, tank {case['initial_tank'] / 1e6:g} -> "
        f"{case['final_tank'] / 1e6:g} MPa, ramp {case['ramp_time']:g} s"
    )


def faulty_envelope(params, only=''):
    """Judge every faulty case (only: those whose case_text contains it); return the runs."""
    began, runs = time.perf_counter(), []
    for case in (case for case in faulty_cases() if only in case_text(case)):
        run = judged_run(params, **case)
        runs.append(run)
        if run.verdict == 'wrong':
            print(f'wrong: {run.case}: {run.reason}', flush=True)
    counts = Counter(run.verdict for run in runs)
    print(
        f'faulty envelope: {len(runs)} runs in {time.perf_counter() - began:.0f} s: '
        + ', '.join(f'{verdict} {counts[verdict]}' for verdict in ('correct', 'refused', 'wrong'))
    )
    for run in (run for run in runs if run.ran_on):
        print(f'judged at {run.ran_on:g} s: {run.case}: {run.verdict}: {run.reason}')
    return runs


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--json', metavar='FILE', help='write every run as JSON')
    parser.add_argument('--faults-only', action='store_true', help='the faulty envelope only')
    parser.add_argument('--only', default='', metavar='TEXT',
                        help="faulty cases whose text contains TEXT (e.g. 'tank 0 -> 34')")
    args = parser.parse_args()
    params = load_parameters().params
    judged = faulty_envelope(params, args.only)
    wrong = any(run.verdict == 'wrong' for run in judged)
    if args.faults_only:
        return 1 if wrong else 0
    began, runs = time.perf_counter(), []
    for preset in PRESETS:
        for initial in FLOWS:
            for final in FLOWS:
                if initial == final:
                    continue
                for ramp in (0.0, RAMP_TIME):
                    run = envelope_run(
                        params, preset, initial * LITRE_PER_MINUTE, final * LITRE_PER_MINUTE, ramp
                    )
                    runs.append(run)
                    if not run.good:
                        print(
                            f'{run.outcome}: preset {preset / 1e6:g} MPa, {initial:g} -> '
                            f'{final:g} L/min, ramp {ramp:g} s: {run.message}',
                            flush=True,
                        )
    elapsed = time.perf_counter() - began
    counts = Counter(run.outcome for run in runs)
    print(
        f'{len(runs)} runs in {elapsed:.0f} s: '
        + ', '.join(f'{outcome} {count}' for outcome, count in sorted(counts.items()))
    )
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(
                [
                    {
                        'preset_pressure': run.preset_pressure,
                        'initial_flow': run.initial_flow,
                        'final_flow': run.final_flow,
                        'ramp_time': run.ramp_time,
                        'outcome': run.outcome,
                        'end_pressure': run.end_pressure,
                        'steady_pressure': run.steady_pressure,
                        'message': run.message,
                    }
                    for run in runs
                ],
                stream,
                indent=1,
            )
    return 0 if all(run.good for run in runs) and not wrong else 1


if __name__ == '__main__':
    sys.exit(main())
