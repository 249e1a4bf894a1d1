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

"""The model across its envelope: presets 3-10 MPa, flows 0-25 L/min (coarse; bench/ has all)."""

import pytest
from valve_sim.analysis.steps.envelope import envelope_run, judged_run
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.core.faults import HEALTHY
from valve_sim.core.simulation import LITRE_PER_MINUTE


LPM = LITRE_PER_MINUTE
COARSE = [  # (initial flow, final flow, ramp time): from closed, steps up and down, a ramp
    (0.0, 25 * LPM, 0.0),
    (0.0, 25 * LPM, 0.2),
    (5 * LPM, 25 * LPM, 0.0),
    (25 * LPM, 1 * LPM, 0.0),
    (25 * LPM, 0.0, 0.0),
]


@pytest.mark.parametrize('preset', [3e6, 10e6])
def test_no_divergence_or_stall_across_the_envelope(reference, preset):
    for initial, final, ramp in COARSE:
        run = envelope_run(reference, preset, initial, final, ramp)
        assert run.good, (preset, initial / LPM, final / LPM, ramp, run.outcome, run.message)
        for name in MEASURE_NAMES:  # a value, or the reason why there is none
            assert run.measures[name] is not None or name in run.measures['reasons']
        if initial == 0.0:
            assert 'empty and closed' in run.measures['reasons']['P_o_percent']


def test_a_flow_the_pilot_passes_alone_says_the_main_stage_stayed_shut(reference):
    run = envelope_run(reference, 7e6, 0.2 * LPM, 0.5 * LPM)
    assert run.outcome == 'pilot relieves'
    assert 'stayed on its seat' in run.measures['reasons']['T_s_ms']


# A sample of bench/bench_envelope.py's faulty envelope: the issue-40 kinds of case.
FAULTY_SAMPLE = [  # (fault changes, initial/final flow, initial/final tank pressure, ramp)
    ({'fault.pilot_spring_weakening': 1.0}, 5 * LPM, 20 * LPM, 0.0, 10e6, 0.0),
    ({'fault.seat_leakage_diameter': 2e-3}, 20 * LPM, 3 * LPM, 0.0, 10e6, 0.05),
    ({'fault.bearing_orifice_blockage': 1.0}, 5 * LPM, 5 * LPM, 0.0, 0.0, 0.0),
    ({}, 5 * LPM, 5 * LPM, 10e6, 0.0, 0.0),
]


@pytest.mark.parametrize('case', FAULTY_SAMPLE)
def test_faulty_runs_are_correct_or_refused_judged_independently(reference, case):
    changes, initial, final, tank_initial, tank_final, ramp = case
    run = judged_run(
        reference, HEALTHY.changed(changes), initial, final, tank_initial, tank_final, ramp,
        end_time=0.6,
    )
    assert run.verdict in ('correct', 'refused'), (run.case, run.reason)


def test_a_run_still_moving_at_its_end_is_run_on_and_judged_over_whole_cycles(reference):
    """
    A cavitating, chattering stretch is judged where it settles: run on to 2 s.

    Bearing orifices 90 % blocked, the tank stepped 10 -> 0 MPa: the pilot stage cavitates
    and the main valve chatters for 0.5 s, and at 1 s the refill is under way (its timing
    differs with the step); by 2 s the valve hunts in a 42.5 ms limit cycle. Judged over
    whole cycles it agrees with its quarter step and keeps the flow balance.
    """
    run = judged_run(reference, HEALTHY.changed({'fault.bearing_orifice_blockage': 0.9}),
                     5 * LPM, 5 * LPM, 10e6, 0.0)
    assert (run.verdict, run.ran_on) == ('correct', 2.0), run.reason
    assert 'flow balance holds' in run.reason


def test_whole_cycles_weigh_a_limit_cycle_evenly():
    """A window of 1.2 periods biases the mean of a sine; whole cycles do not."""
    import numpy as np
    from valve_sim.analysis.steps.envelope import _whole_cycles

    time = np.arange(0.0, 2.0, 1e-4)
    p_s = 6.5e6 + 2e5 * np.sin(2 * np.pi * time / 0.0425 + 0.3)
    cut = time >= time[-1] - 0.05
    assert abs(np.mean(p_s[cut]) - 6.5e6) > 2e3
    assert np.mean(p_s[_whole_cycles(time, p_s, 0.5)]) == pytest.approx(6.5e6, abs=2e2)
