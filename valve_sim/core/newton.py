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
A small damped Newton solver for square nonlinear systems, numpy only.

The steady state's balances (valve_sim.core.steady_state) are solved here rather
than by scipy.optimize.root, whose import alone costs valve_node's start about
0.3 s (issue 29). find_root tries Newton and, only if Newton does not reach the
tolerance, imports scipy and runs MINPACK's hybr from the same start: the same
answers where Newton fails (a kink of the orifice law, a singular Jacobian).

The unknowns should be scaled to order 1 and the residuals made relative (as the
steady state does), since the tolerances below are absolute on those.
"""

from collections import namedtuple

import numpy as np


NewtonResult = namedtuple('NewtonResult', 'x residual iterations converged method')
NewtonResult.__doc__ = """
Where a solver stopped.

x: the last accepted point; residual: max |f(x)| there; iterations: Newton steps
taken (0 for hybr); converged: residual <= the tolerance asked for; method: 'newton'
or 'hybr' (the fallback).
"""

STEP_TOLERANCE = 1e-13  # relative: stop once a step moves x by less (hybr's xtol as used here)
MAX_ITERATIONS = 100
MIN_DAMPING = 2.0 ** -12  # the smallest fraction of a Newton step the line search tries
DIFFERENCE_STEP = np.sqrt(np.finfo(float).eps)  # relative forward-difference step


def difference_jacobian(function, x, fx):
    """Forward-difference Jacobian [n x n] of function at x, given fx = function(x)."""
    matrix = np.empty((len(fx), len(x)))
    for j in range(len(x)):
        h = DIFFERENCE_STEP * max(abs(x[j]), 1.0)
        moved = x.copy()
        moved[j] += h
        matrix[:, j] = (function(moved) - fx) / (moved[j] - x[j])
    return matrix


def newton(function, x0, tolerance, jacobian=None):
    """
    Damped Newton's method for function(x) = 0 from x0; return a NewtonResult.

    function maps an n-array to an n-array; jacobian(x) gives its [n x n] derivative
    (default: forward differences, difference_jacobian). Each step solves
    J dx = -f(x) and takes the largest of dx, dx/2, dx/4, ... (down to MIN_DAMPING dx)
    that lowers |f| (2-norm) by at least a 1e-4 share of that fraction (Armijo).
    Stops when a step moves x by less than STEP_TOLERANCE relative to max |x|, when f
    is exactly 0, when no fraction of the step lowers |f| (f is then at rounding
    level or Newton is stuck), when J is singular or f not finite, or after
    MAX_ITERATIONS steps. Iterating past the tolerance polishes the root to rounding
    level, as hybr with a tight xtol does. converged: max |f(x)| <= tolerance at
    the point where it stopped; x is then a root to that tolerance, else the best
    point reached (never one where f is not finite, unless x0 is).
    """
    x = np.array(x0, dtype=float)
    fx = np.asarray(function(x), dtype=float)
    iterations = 0
    while iterations < MAX_ITERATIONS and np.all(np.isfinite(fx)) and np.any(fx):
        matrix = jacobian(x) if jacobian is not None else difference_jacobian(function, x, fx)
        try:
            step = np.linalg.solve(matrix, -fx)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(step)):
            break
        size = np.linalg.norm(fx)
        damping = 1.0
        while damping >= MIN_DAMPING:
            trial = x + damping * step
            f_trial = np.asarray(function(trial), dtype=float)
            if np.all(np.isfinite(f_trial)) and (
                np.linalg.norm(f_trial) <= (1.0 - 1e-4 * damping) * size
            ):
                break
            damping /= 2.0
        else:
            break
        iterations += 1
        moved = np.max(np.abs(trial - x))
        x, fx = trial, f_trial
        if moved <= STEP_TOLERANCE * (np.max(np.abs(x)) + STEP_TOLERANCE):
            break
    residual = np.max(np.abs(fx))
    return NewtonResult(x, residual, iterations, bool(residual <= tolerance), 'newton')


def hybr(function, x0, tolerance):
    """Run MINPACK's hybr method of scipy.optimize.root from x0 (imported only now)."""
    from scipy.optimize import root  # 0.3 s to import: only when Newton failed

    solution = root(function, np.asarray(x0, dtype=float), method='hybr',
                    options={'xtol': STEP_TOLERANCE})
    residual = np.max(np.abs(function(solution.x)))
    return NewtonResult(solution.x, residual, 0, bool(residual <= tolerance), 'hybr')


def find_root(function, x0, tolerance, jacobian=None):
    """
    Root of function near x0: Newton (newton), then hybr from x0 if Newton fails.

    Returns the NewtonResult of whichever converged, else the one with the smaller
    residual (converged False): the caller decides what an unsolved system means.
    """
    result = newton(function, x0, tolerance, jacobian)
    if result.converged:
        return result
    fallback = hybr(function, x0, tolerance)
    if fallback.converged or np.isnan(result.residual) or fallback.residual < result.residual:
        return fallback
    return result
