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
A bench scenario's verdict: report.txt, report.json, junit.xml and scenario.png.

Each expectation's limit is one check with what was measured (valve_sim.analysis.
expectations.Check). The JUnit file has one test case per check (a failure with the
measured value for one that does not hold, the measured value as its system-out for
one that holds; for a run that could not complete, the checks of what it measured up
to the failure and one error case), so any CI shows the result. The figure draws p_s,
the valve positions and the inlet flow over the run, the events and the limits of the
checks that bound a signal. A failed run's report.txt, report.json and figure say the
error and show the states recorded up to it. A suite of scenarios gets one JUnit file
with a testsuite per scenario, and a summary listing each (write_suite_reports).
"""

from datetime import datetime, timezone
import socket
import xml.etree.ElementTree as ElementTree

import numpy as np
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.core.output_files import json_text, replacing, write_text, xml_bytes


STEP_KEYS = ('t_step', 'direction', 'flow_before', *MEASURE_NAMES, 'reasons')


def verdict(checks):
    failed = sum(not check.passed for check in checks)
    return 'PASSED' if checks and not failed else 'FAILED', failed


def invariant_alarms(run):
    """Return valve_node's invariant alarms that fired in the run ('name: count, ...'), or ''."""
    counts = getattr(run, 'invariant_alarms', '') or ''
    return ', '.join(part for part in counts.split(', ') if part and not part.endswith(': 0'))


def report_text(run):
    """Return the report as text: the verdict, how the run went, one line per check."""
    scenario = run.scenario
    word, failed = verdict(run.checks)
    states = 0 if run.series is None else len(run.series)
    lines = [
        f'scenario {scenario.name} ({scenario.path}): {"ERROR" if run.error else word}, '
        f'{len(run.checks) - failed} of {len(run.checks)} checks hold',
        f'  {scenario.duration:g} s of model time, {states} states of valve_node in '
        f'lockstep in {run.wall_s:.2f} s'
        + (f' ({run.speed:.2f}x real time)' if run.speed and not run.error else ''),
        f'  bag {run.bag}',
    ]
    if run.error:
        lines[2:2] = [f'  ERROR: the run did not complete: {run.error}',
                      f'  the checks below judge the {states} states recorded up to the failure']
    alarms = invariant_alarms(run)
    if alarms:  # valve_sim.core.invariants: valve_node's counts on /diagnostics
        lines.append(f'  WARNING: invariant alarms of valve_node: {alarms}')
    if scenario.description:
        lines.insert(1, f'  {scenario.description}')
    width = max((len(check.name) for check in run.checks), default=0)
    for check in run.checks:
        lines.append(f'  {"PASS" if check.passed else "FAIL"}  {check.name:<{width}}  '
                     f'measured {check.shown}  ({check.detail})')
    return '\n'.join(lines) + '\n'


def report_document(run):
    """Return the report as a JSON-ready dict: the checks (measured values), run and steps."""
    scenario = run.scenario
    return {
        'scenario': scenario.name,
        'file': str(scenario.path),
        'passed': run.passed,
        'error': run.error,
        'invariant_alarms': invariant_alarms(run),
        'checks': [check.as_dict() for check in run.checks],
        'run': {
            'duration_s': scenario.duration,
            'states': 0 if run.series is None else len(run.series),
            'period_s': scenario.period_ns / 1e9,
            'first_stamp_ns': run.start_ns,
            'wall_s': run.wall_s,
            'clock_steps': run.clock_steps,
            'real_time_factor': run.speed,
            'bag': str(run.bag),
        },
        'steps': [{key: record[key] for key in STEP_KEYS} for record in run.steps],
    }


def junit_document(scenario, checks, wall_s=0.0, error=None):
    """Return the JUnit XML of a run as bytes: a test case per check, and the error's case."""
    return suite_junit_document([(scenario, checks, wall_s, error)])


def suite_junit_document(runs):
    """
    Return the JUnit XML of runs [(scenario, checks, wall_s, error)] as bytes.

    One testsuite per run (a suite of scenarios has one per scenario): a test case
    per check, and the error's case for a run that did not complete.
    """
    totals = dict.fromkeys(('tests', 'failures', 'errors'), 0)
    suites = ElementTree.Element('testsuites', name='valve-sim scenario')
    for scenario, checks, wall_s, error in runs:
        counts = _testsuite(suites, scenario, checks, wall_s, error)
        for key in totals:
            totals[key] += counts[key]
    suites.attrib.update({key: str(value) for key, value in totals.items()},
                         skipped='0', time=f'{sum(run[2] for run in runs):.3f}')
    return xml_bytes(suites)


def _testsuite(suites, scenario, checks, wall_s, error):
    """Add a run's testsuite to suites; return its counts."""
    _, failed = verdict(checks)
    counts = {'tests': len(checks) + (error is not None), 'failures': failed,
              'errors': int(error is not None)}
    suite = ElementTree.SubElement(
        suites, 'testsuite', name=scenario.name, hostname=socket.gethostname(),
        timestamp=datetime.now(timezone.utc).isoformat(timespec='seconds'),
        skipped='0', time=f'{wall_s:.3f}', **{key: str(value) for key, value in counts.items()})
    properties = ElementTree.SubElement(suite, 'properties')
    ElementTree.SubElement(properties, 'property', name='file', value=str(scenario.path))
    for check in checks:
        case = ElementTree.SubElement(suite, 'testcase', classname=f'scenario.{scenario.name}',
                                      name=check.name, time='0')
        if not check.passed:
            failure = ElementTree.SubElement(
                case, 'failure', message=f'measured {check.shown}, expected {check.limit}')
            failure.text = check.detail
        else:  # CI shows it beside the case: what a passing check measured
            ElementTree.SubElement(case, 'system-out').text = (
                f'measured {check.shown}, expected {check.limit} ({check.detail})')
    if error is not None:
        case = ElementTree.SubElement(suite, 'testcase', classname=f'scenario.{scenario.name}',
                                      name='run', time=f'{wall_s:.3f}')
        ElementTree.SubElement(case, 'error', message=error).text = error
    return counts


def plot_run(path, run):
    """Draw p_s (and p_t if driven), x and y, q_in and q_r over the run, with events and limits."""
    from valve_sim.analysis.scenarios.expectations import Bound
    from valve_sim.analysis.plotting import plt, save_figure

    series, scenario = run.series, run.scenario
    # fixed margins (the labels' sizes do not change): a constrained layout's extra draw
    # pass was half the figure's cost, which every scenario of a suite pays
    figure, axes = plt.subplots(3, 1, sharex=True, figsize=(9, 8),
                                gridspec_kw={'left': 0.085, 'right': 0.985, 'top': 0.955,
                                             'bottom': 0.065, 'hspace': 0.08})
    if series is None:  # nothing recorded: the figure says so, and why
        axes[0].set_title(f'scenario {scenario.name}: ERROR, no state recorded')
        axes[1].text(0.5, 0.5, run.error, ha='center', va='center', wrap=True,
                     transform=axes[1].transAxes, fontsize='small')
        save_figure(figure, path, dpi=110)
        return
    for expectation in scenario.expectations:
        if isinstance(expectation, Bound) and expectation.signal == 'supply_pressure':
            axes[0].axhline(expectation.value * 1e-6, color='tab:red', linestyle='--',
                            linewidth=0.8)
    limits = scenario.supply_pressure_limits()[:len(series)]
    if np.any(limits > 0):
        axes[0].step(series.time, np.where(limits > 0, limits, np.nan) * 1e-6, where='pre',
                     color='0.4', linestyle=':', linewidth=0.8, label='supply_pressure_limit')
    pressures = [('supply_pressure', 'tab:blue', 'p_s, supply')]
    if 'tank_pressure' in scenario.inputs:  # the back pressure the scenario drives
        pressures.append(('tank_pressure', 'tab:brown', 'p_t, tank (applied)'))
    _traces(axes[0], series, pressures, 1e-6, 'pressure [MPa, gauge]')
    _traces(axes[1], series, [('main_valve', 'tab:red', 'x, main valve'),
                              ('pilot_poppet', 'tab:green', 'y, pilot poppet')],
            1e3, 'position [mm]')
    _traces(axes[2], series, [('inlet_flow', 'tab:purple', 'q_in, inlet (applied)'),
                              ('relief_flow', 'tab:cyan', 'q_r, relief to the tank')],
            6e4, 'flow [L/min]')
    axes[2].set_xlabel('time from the first tick [s]')
    for event in scenario.events:
        for axis in axes:
            axis.axvline(event.time_ns / 1e9, color='tab:orange', linestyle='--', linewidth=0.8)
        axes[0].annotate(', '.join(event.changes), (event.time_ns / 1e9, 1.0),
                         xycoords=('data', 'axes fraction'), fontsize='x-small',
                         rotation=90, va='top', ha='right', color='tab:orange')
    for axis in axes:
        axis.grid(True, alpha=0.3)
    word, failed = verdict(run.checks)
    axes[0].set_title(f'scenario {scenario.name}: {"ERROR" if run.error else word} '
                      f'({len(run.checks) - failed} of {len(run.checks)} checks hold)'
                      + (f', stopped at {series.time[-1]:.3f} s' if run.error else ''))
    save_figure(figure, path, dpi=110)


def _traces(axis, series, signals, scale, label):
    """Plot signals [(name, colour, legend text)] of series times scale, labelled, on axis."""
    for name, colour, text in signals:
        axis.plot(series.time, series[name] * scale, color=colour, linewidth=0.9, label=text)
    axis.set_ylabel(label)
    axis.legend(loc='best', fontsize='small')


def write_junit(document, folder, junit_path=None):
    """Write JUnit XML bytes to junit_path (the user's, a link followed) or folder/junit.xml."""
    path = junit_path or folder / 'junit.xml'
    with replacing(path, 'wb', explicit=junit_path is not None) as stream:
        stream.write(document)
    return path


def write_reports(run, junit_path=None, plot=plot_run):
    """
    Write report.txt, report.json, scenario.png and junit.xml (or junit_path); return paths.

    plot(path, run) draws the figure (a suite's draws it while the next scenario runs).
    """
    folder = run.folder
    paths = {
        'report': folder / 'report.txt',
        'json': folder / 'report.json',
        'figure': folder / 'scenario.png',
    }
    write_text(paths['report'], report_text(run))
    write_text(paths['json'], json_text(report_document(run)) + '\n')
    plot(paths['figure'], run)
    paths['junit'] = write_junit(
        junit_document(run.scenario, run.checks, run.wall_s, run.error), folder, junit_path
    )
    return paths


def suite_summary(runs):
    """Return a suite's summary as text: a line per run (its verdict and folder), the totals."""
    lines = []
    for run in runs:
        word, failed = verdict(run.checks)
        lines.append(f'  {"ERROR" if run.error else word:6} {run.scenario.name}: '
                     f'{len(run.checks) - failed} of {len(run.checks)} checks hold '
                     f'({run.folder})' + (f'; {run.error}' if run.error else ''))
    passed = sum(run.passed for run in runs)
    return '\n'.join([f'suite: {passed} of {len(runs)} scenarios passed', *lines]) + '\n'


def write_suite_reports(runs, folder, junit_path=None):
    """Write a suite's summary.txt and junit.xml (one testsuite per run); return their paths."""
    paths = {'summary': folder / 'summary.txt'}
    write_text(paths['summary'], suite_summary(runs))
    paths['junit'] = write_junit(suite_junit_document(
        [(run.scenario, run.checks, run.wall_s, run.error) for run in runs]), folder, junit_path)
    return paths
