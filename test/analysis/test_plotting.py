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
What the step-response figures say: panel labels, units, titles (issue 8).

The plotting functions write PNG files; these tests catch each matplotlib Figure as
it is saved and read its axes, so what a person sees is checked, not only that a
file was written.
"""

import json
from pathlib import Path
import re

from matplotlib.figure import Figure
import numpy as np
import pytest
from valve_sim.analysis.plotting import plot_step_response
from valve_sim.analysis.recorded_steps import PLOT_LEAD, plot_steps
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, simulate
from valve_sim.recording.signal_reader import read_recording


BAGS = Path(__file__).resolve().parents[2] / 'bags'


@pytest.fixture
def saved(monkeypatch):
    """Collect every Figure saved from now on (it is still written to its file)."""
    figures = []
    save = Figure.savefig

    def savefig(figure, *args, **kwargs):
        figures.append(figure)
        return save(figure, *args, **kwargs)

    monkeypatch.setattr(Figure, 'savefig', savefig)
    return figures


def panels(figure):
    """Return [(y label, y data of the panel's curve)] of a step-response figure, top down."""
    return [(axis.get_ylabel(), axis.get_lines()[0].get_ydata()) for axis in figure.axes]


def test_a_step_from_the_closed_valve_is_drawn_in_mpa_and_mm(reference, saved, tmp_path):
    """p_s and x are zero at the step: no ratio to them, the panels show MPa and mm."""
    run = simulate(
        reference,
        FlowStep(0.0, 20.0 * LITRE_PER_MINUTE, step_time=0.05, end_time=0.3),
        record_interval=1e-4,
    )
    plot_step_response(
        tmp_path / 'closed.png',
        run.time,
        run['supply_pressure'],
        run['main_valve_displacement'],
        run['poppet_displacement'],
        0.05,
    )
    (figure,) = saved
    (p_label, p_drawn), (x_label, x_drawn), (y_label, y_drawn) = panels(figure)
    assert p_label == 'p_s [MPa]\n(0 at the step)'
    assert x_label == 'x [mm]\n(0 at the step)'
    assert y_label == 'y [mm]\n(0 at the step)'
    np.testing.assert_allclose(p_drawn, run['supply_pressure'] * 1e-6)
    np.testing.assert_allclose(x_drawn, run['main_valve_displacement'] * 1e3)
    np.testing.assert_allclose(y_drawn, run['poppet_displacement'] * 1e3)
    assert 5.0 < p_drawn.max() < 10.0, 'the relieving pressure, some 7 MPa'
    assert (tmp_path / 'closed.png').stat().st_size > 10_000


def test_a_step_from_a_relieving_valve_is_drawn_relative_to_its_value_at_the_step(
    tick_waveforms, saved, tmp_path
):
    run, t_step = tick_waveforms, 0.1
    plot_step_response(
        tmp_path / 'open.png',
        run.time,
        run['supply_pressure'],
        run['main_valve_displacement'],
        run['poppet_displacement'],
        t_step,
    )
    (p_label, p_drawn), (x_label, _), (y_label, _) = panels(saved[0])
    assert (p_label, x_label, y_label) == (
        'P = p_s / p_s(t_step) [-]',
        'X = x / x(t_step) [-]',
        'Y = y / y(t_step) [-]',
    )
    at_step = run['supply_pressure'][run.time <= t_step][-1]
    np.testing.assert_allclose(p_drawn, run['supply_pressure'] / at_step)
    assert p_drawn[run.time <= t_step][-1] == 1.0


def test_the_figure_of_a_recorded_step_counts_time_from_the_first_sample(saved, tmp_path):
    """The bag's time axis is the epoch; title and time axis start from the recording."""
    bag = BAGS / 'reference_step.mcap'
    recording = read_recording(bag)
    (record,) = json.loads(bag.with_suffix('.measures.json').read_text())['steps']
    assert recording.time[0] > 1e9, 'this bag is stamped with the epoch'
    plot_steps(tmp_path / 'figure5.png', recording, [record])
    (figure,) = saved
    title = figure.axes[0].get_title()
    after = record['t_step'] - recording.time[0]
    assert title == (
        f'Recorded step 1, {after:.4f} s after the first sample, shown at {PLOT_LEAD:g} s'
    )
    assert all(float(number) < 1e3 for number in re.findall(r'[0-9.]+', title))
    drawn = figure.axes[0].get_lines()[0].get_xdata()
    assert drawn[0] >= 0.0 and drawn[-1] < 2.0
    assert figure.axes[-1].get_xlabel() == 'time [s]'


def test_the_fit_figure_shows_the_recording_above_the_model(reference, saved, tmp_path):
    """fit.png: recorded samples as dots drawn over the model's line, the step zoomed."""
    from valve_sim.analysis.calibration.targets import RecordingTarget
    from valve_sim.analysis.plotting import plot_recording_fit

    run = simulate(reference, FlowStep(step_time=0.1, end_time=0.5), record_interval=1e-3)
    target = RecordingTarget(run.time, run['supply_pressure'], run.inlet_flow,
                             run['main_valve_displacement'])
    plot_recording_fit(tmp_path / 'fit.png', target, run.states)
    (figure,) = saved
    zoomed, whole = figure.axes[0], figure.axes[1]
    for axis in (zoomed, whole, figure.axes[3]):
        model, recorded = axis.get_lines()
        assert recorded.get_label() == 'recorded' and recorded.get_linestyle() == 'None'
        assert recorded.get_zorder() > model.get_zorder()
    assert zoomed.get_lines()[0].get_xdata().max() <= 0.1 + 0.2 + 1e-9  # the first step
    assert figure.axes[3].get_ylabel() == 'main valve x [µm]'


def test_tolerance_figures_show_readable_units_and_limits_beside_their_lines(saved, tmp_path):
    from valve_sim.analysis.studies.plots import plot_measures_against
    from valve_sim.analysis.studies.tolerances import parse_limits

    values = np.array([0.98e-3, 1.0e-3, 1.02e-3])  # d_c [m]
    rows = [{'measures': {name: 1.0 + k for name in MEASURE_NAMES}, 'error': None,
             'reasons': {}} for k in range(3)]
    plot_measures_against(tmp_path / 'vs.png', 'damping_orifice_diameter', 'm', values, rows,
                          parse_limits('P_1_percent<=2.5'))
    (figure,) = saved
    axis = figure.axes[MEASURE_NAMES.index('P_1_percent')]
    assert axis.get_xlabel() == 'damping_orifice_diameter [mm]'
    np.testing.assert_allclose(sorted(axis.get_lines()[0].get_xdata()), [0.98, 1.0])
    (label,) = axis.texts
    assert label.get_text() == 'P_1_percent<=2.5' and label.xyann == (0, 3)  # above the line


@pytest.mark.parametrize('unit, values, expected', [
    ('m', [2.1e-5], (1e6, 'µm')), ('m', [1e-3], (1e3, 'mm')), ('N/m', [158000.0], (1e-3, 'N/mm')),
    ('kg', [0.065], (1e3, 'g')), ('1', [0.5], (1.0, '1')),
])
def test_parameters_are_shown_in_the_unit_a_person_reads(unit, values, expected):
    from valve_sim.analysis.studies.plots import display_unit

    assert display_unit(unit, np.array(values)) == expected
