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
Parameter identification: fit chosen model parameters to step measures or to a recording.

One implementation for the paper's Figure 5 and for a rig's own valve, in three parts:
- what is fitted: FitParameters, ties, the values applied (calibration.parameters);
- what it is fitted to: a MeasuresTarget or RecordingTarget (calibration.targets);
- what the fitted valve must meet: Constraints, which add residuals that are zero while
  they hold, and Checks, which judge each start's result (calibration.requirements);
and the fit itself, here: calibrate(problem, settings). scipy.optimize.least_squares
(trust region reflective, bounds) runs from several starts; the best start that meets
every constraint and check wins. Approximate 95 % intervals and correlations come
from the Jacobian at the result (calibration.uncertainty).
A caller stops a fit by its should_stop callback (the command line's Ctrl-C): the
result is then the best evaluation so far, marked interrupted.

About 400 lines on purpose: the fit's objective, starts, search and result in one
module; what is fitted, to what, and its judgement live beside it in this room.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
import math
import time as clock
from typing import Optional

import numpy as np
from scipy.optimize import least_squares
from valve_sim.analysis.calibration.parameters import apply_values, start_value, STEP_TIME
from valve_sim.analysis.calibration.uncertainty import add_uncertainty, central_jacobian
from valve_sim.core.errors import CalibrationError, MODEL_ERRORS


FAILED_RESIDUAL = 1e3  # every residual of a parameter set the model cannot run
FLAT_CHANGE = 1e-9  # relative residual change below which a parameter is flat


@dataclass(frozen=True)
class CalibrationProblem:
    """
    What to fit, to what, under what: the question a calibration answers.

    params: validated parameters (the fitted ones start at their values there);
    fitted: FitParameters (calibration.parameters.fit_parameters, step_time_parameters);
    target: a MeasuresTarget or RecordingTarget; constraints: Constraints (their
    penalties join the residuals); checks: Checks judged per start after its fit;
    preset_pressure [Pa]: held during the fit (the preload re-solved) unless fitted;
    ties: {tied: (fitted parameter it follows, factor)} (fit_ties).
    """

    params: Mapping[str, float]
    fitted: list
    target: object
    constraints: tuple = ()
    checks: tuple = ()
    preset_pressure: Optional[float] = None
    ties: dict = field(default_factory=dict)


@dataclass(frozen=True)
class FitSettings:
    """
    How the fit searches: its starts, tolerances and evaluation budget.

    starts: how many (the first is the problem's params); spread: log-normal standard
    deviation of the others; seed: their generator's; tolerance: ftol = xtol = gtol of
    least_squares; diff_step: relative finite-difference step (None: 1e-6 for a
    recording, 1e-4 for measures); max_evaluations: per start.
    """

    starts: int = 3
    spread: float = 0.1
    seed: int = 0
    tolerance: float = 1e-10
    diff_step: Optional[float] = None
    max_evaluations: int = 2000


@dataclass
class CalibrationResult:
    """What calibrate() found; values in SI, intervals approximate (Jacobian)."""

    parameters: dict
    fitted: list
    values: list[float]
    start_values: list[float]
    residuals: np.ndarray
    residual_names: list
    cost: float
    intervals: Optional[list] = None  # [(low, high)] or None when not computed
    correlations: Optional[np.ndarray] = None
    uncertainty_note: Optional[str] = None  # why there are no intervals or correlations
    flat: list = field(default_factory=list)
    constraints: list = field(default_factory=list)
    starts: list = field(default_factory=list)
    evaluations: int = 0
    wall_time: float = 0.0
    interrupted: bool = False
    ties: dict = field(default_factory=dict)
    rank: Optional[int] = None  # combinations of the fitted parameters the target determines
    jacobian: Optional[np.ndarray] = None  # d(residuals)/du at the result (calibration.verdict)

    @property
    def satisfied(self) -> bool:
        return all(status['satisfied'] for status in self.constraints)

    @property
    def status(self) -> int:
        """0: the fit ran to its end; 1: it was interrupted (as scipy's OptimizeResult)."""
        return 1 if self.interrupted else 0

    @property
    def message(self) -> str:
        """Say what status means, in one line."""
        return 'interrupted: the best evaluation so far' if self.interrupted else 'fitted'


class _Stopped(Exception):
    """The caller's should_stop() said stop: unwinds least_squares to calibrate()."""


class _Objective:
    """Residuals of normalised values u = value / start; remembers the best evaluation."""

    def __init__(self, problem, start, progress, should_stop):
        self.problem, self.start = problem, np.asarray(start, dtype=float)
        self.progress, self.should_stop, self.stopped = progress, should_stop, False
        self.count, self.best = 0, (math.inf, None)
        self.size = None
        self.label, self.last_report = '', 0.0
        self.failure = None  # why the last failed evaluation failed
        self.failed, self.largest = False, 0.0  # the last evaluation failed; largest |residual|

    def parameters(self, u):
        problem = self.problem
        return apply_values(
            problem.params, problem.fitted, u * self.start, problem.preset_pressure, problem.ties
        )

    def use_step_times(self, u):
        """Hand the fitted step times of u to the target."""
        times = [
            v for p, v in zip(self.problem.fitted, u * self.start) if p.name.startswith(STEP_TIME)
        ]
        if times:
            self.problem.target.step_times = times

    def __call__(self, u):
        if not self.stopped and self.should_stop is not None and self.should_stop():
            self.stopped = True  # asked once: the evaluations after it (the result's) run
            raise _Stopped
        self.count += 1
        self.use_step_times(u)
        target, constraints = self.problem.target, self.problem.constraints
        try:
            params = self.parameters(u)
            residual = np.concatenate(
                [target.residuals(params), [c.penalty(params) for c in constraints]]
            )
        except MODEL_ERRORS as error:
            residual, self.failure = None, f'the model cannot run it: {error}'
        if self.size is None and residual is not None:
            self.size = len(residual)
        if residual is not None and not np.all(np.isfinite(residual)):
            residual, self.failure = None, _non_finite(target, residual)
        self.failed = residual is None
        if residual is None:  # worse than any residual seen, so that the search leaves it
            residual = np.full(self.size or 1, max(FAILED_RESIDUAL, 10.0 * self.largest))
        else:
            self.largest = max(self.largest, float(np.max(np.abs(residual), initial=0.0)))
        cost = 0.5 * float(residual @ residual)
        if cost < self.best[0] and not self.failed:
            self.best = (cost, np.array(u, dtype=float))
        now = clock.monotonic()
        if self.progress and now - self.last_report >= 0.5:
            self.last_report = now
            self.progress(
                f'{self.label} evaluation {self.count}: cost {cost:.6g}, best {self.best[0]:.6g}'
            )
        return residual


def _non_finite(target, residual):
    """Say which residuals are not finite although the model ran: a problem of the data."""
    names = sorted({name for name, value in zip(target.residual_names, residual)
                    if not math.isfinite(value)})
    return (
        f'the residuals of {", ".join(names) or "the constraints"} are not finite although '
        'the model ran: the target holds NaN or infinite values, or a noise level that is '
        'not finite (a problem of the data, not of the model)'
    )


def _starts(fitted, start, count, spread, seed):
    """Start points in normalised units: the file's values, then seeded log-normal ones."""
    rng = np.random.default_rng(seed)
    lower = np.array([p.lower for p in fitted]) / start
    upper = np.array([p.upper for p in fitted]) / start
    points = [np.ones(len(fitted))]
    for _ in range(count - 1):
        points.append(np.clip(np.exp(spread * rng.standard_normal(len(fitted))), lower, upper))
    return points, (lower, upper)


def calibrate(
    problem: CalibrationProblem, settings: FitSettings = FitSettings(),
    progress: Optional[Callable[[str], object]] = None,
    should_stop: Optional[Callable[[], bool]] = None,
) -> CalibrationResult:
    """
    Fit problem.fitted to problem.target from settings.starts starts; a CalibrationResult.

    progress(line): called with progress lines (at most every 0.5 s); should_stop():
    asked before every model evaluation, a true answer ends the fit: the result is
    then the best evaluation so far, marked interrupted. Raises CalibrationError for
    a flat (not identifiable) parameter, a start the model cannot run, or a stop
    before the first evaluation finished.
    """
    began = clock.monotonic()
    start = np.array([
        p.start if p.start is not None else start_value(problem.params, p.name)
        for p in problem.fitted
    ])
    objective = _Objective(problem, start, progress, should_stop)
    objective.label = 'identifiability check:'
    try:
        _check_identifiable(objective)
    except _Stopped:
        if objective.best[1] is None:
            raise CalibrationError('interrupted before the first evaluation finished') from None
        cost, u = objective.best
        result = _result(objective, u, cost, constraints=[], runs=[], interrupted=True)
        result.residuals = objective(u)
        return _finished(result, objective, began)
    runs = _fit_from_starts(objective, settings)
    ran = [run for run in runs if run['u'] is not None]
    if not ran:
        raise CalibrationError('the model cannot run at any start: check the start values')
    feasible = [run for run in ran if all(c['satisfied'] for c in run['checks'])]
    best = min(feasible or ran, key=lambda run: run['cost'])
    u = best['u']
    result = _result(objective, u, best['cost'], best['checks'], runs, objective.stopped)
    if objective.stopped:
        result.residuals = objective(u)
    else:
        relative = _relative_step(problem, settings)
        residual, jacobian = central_jacobian(objective, u, max(relative, 1e-6))
        objective.use_step_times(u)  # the Jacobian moved them
        result.residuals, result.jacobian = residual, jacobian
        add_uncertainty(result, problem.target, jacobian, start)
    return _finished(result, objective, began)


def _relative_step(problem, settings):
    return settings.diff_step or (1e-6 if problem.target.kind == 'recording' else 1e-4)


def _check_identifiable(objective):
    """Raise CalibrationError if the start cannot be run or a fitted parameter is flat."""
    fitted = objective.problem.fitted
    base = objective(np.ones(len(fitted)))
    if objective.failed:
        if objective.failure.startswith('the model'):
            raise CalibrationError(
                'the model cannot run the target with the start values (no steady state or a '
                f'diverging run): check the parameter file and --params ({objective.failure})'
            )
        raise CalibrationError(f'the target cannot be compared: {objective.failure}')
    base, jacobian = central_jacobian(objective, np.ones(len(fitted)), 0.01)
    flat = [
        p
        for p, column in zip(fitted, jacobian.T)
        if np.linalg.norm(column) * 0.01 <= FLAT_CHANGE * (1.0 + np.linalg.norm(base))
    ]
    if flat:
        raise CalibrationError(
            'not identifiable from this target: '
            + ', '.join(f"'{p.name}' ({p.symbol})" for p in flat)
            + ' (moving it by 1 % changes no residual: the residual is flat in it); '
            'drop it from --fit'
        )


def _fit_from_starts(objective, settings):
    """Run least_squares from each start until one is stopped; return the runs (dicts)."""
    problem, start = objective.problem, objective.start
    points, bounds = _starts(
        problem.fitted, start, max(1, settings.starts), settings.spread, settings.seed
    )
    runs = []
    for k, point in enumerate(points, start=1):
        objective.label = f'start {k}/{len(points)}'
        objective.best = (math.inf, None)
        run = _fit_from(objective, point, bounds, settings)
        if run is None:  # stopped before its first evaluation
            break
        runs.append(run)
        if objective.progress and run['values'] is not None:
            passed = all(check['satisfied'] for check in run['checks'])
            objective.progress(
                f'{objective.label}: cost {run["cost"]:.6g} after {objective.count} evaluations; '
                + start_fit_text(problem.target, run['cost'])
                + f'; constraints and checks: {"all met" if passed else "NOT all met"}'
            )
        if objective.stopped:
            break
    if not runs:
        raise CalibrationError('interrupted before any evaluation finished')
    return runs


def start_fit_text(target, cost):
    """Say how far a start's residual RMS lies from the noise (tolerance) it is counted in."""
    from valve_sim.analysis.calibration.verdict import FAR_ABOVE

    count = len(target.residual_names)
    rms = math.sqrt(2.0 * cost / max(count, 1))
    unit = 'noise' if target.kind == 'recording' else 'tolerance'
    limit = FAR_ABOVE if target.kind == 'recording' else 1.0
    return f'residual RMS {rms:.3g} x {unit}' + (
        f', far above {limit:g}: the fit does NOT explain its target' if rms > limit else '')


def _fit_from(objective, point, bounds, settings):
    """
    Fit from one start point (normalised units); return its run, or None if stopped at once.

    The run: start and fitted values, cost, least_squares' message, the status of every
    constraint and check at its result, and u (the normalised result; None if skipped).
    """
    problem, start = objective.problem, objective.start
    try:
        objective(point)
        if objective.failed:
            return {'start': list(point * start), 'values': None, 'cost': math.inf,
                    'message': 'skipped: the model cannot run at this start',
                    'checks': [], 'u': None}
        solution = least_squares(
            objective,
            point,
            bounds=bounds,
            method='trf',
            x_scale=1.0,
            diff_step=_relative_step(problem, settings),
            ftol=settings.tolerance,
            xtol=settings.tolerance,
            gtol=settings.tolerance,
            max_nfev=settings.max_evaluations,
        )
        cost, u, message = float(solution.cost), solution.x, solution.message
        failed = np.all(solution.fun == solution.fun[0]) and solution.fun[0] >= FAILED_RESIDUAL
        if failed and objective.best[1] is not None:  # it ended where the model cannot run
            (cost, u), message = objective.best, f'{message} (its best evaluation that ran)'
    except _Stopped:
        (cost, u), message = objective.best, 'interrupted: best evaluation so far'
    if u is None:
        return None
    run = {'start': list(point * start), 'values': list(u * start), 'cost': cost,
           'message': message, 'u': u}
    try:
        result_params = objective.parameters(u)
        run['checks'] = [
            c.status(result_params) for c in (*problem.constraints, *problem.checks)
        ]
    except MODEL_ERRORS as error:
        run['checks'] = [{'constraint': 'model runs', 'value': str(error), 'satisfied': False}]
    return run


def _result(objective, u, cost, constraints, runs, interrupted):
    """Return the CalibrationResult at u (its residuals and evaluations still to set)."""
    problem, start = objective.problem, objective.start
    return CalibrationResult(
        parameters=objective.parameters(u),
        fitted=problem.fitted,
        values=[float(v) for v in u * start],
        start_values=[float(v) for v in start],
        residuals=None,
        residual_names=list(problem.target.residual_names)
        + [c.name for c in problem.constraints],
        cost=float(cost),
        constraints=constraints,
        starts=[{k: v for k, v in run.items() if k != 'u'} for run in runs],
        interrupted=interrupted,
        ties=dict(problem.ties or {}),
    )


def _finished(result, objective, began):
    result.evaluations = objective.count
    result.wall_time = clock.monotonic() - began
    return result
