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

"""The steady state's damped Newton solver and its fallback to scipy's hybr."""

import numpy as np
import pytest
from valve_sim.core import newton
from valve_sim.core.model import P_S
from valve_sim.core.newton import find_root
from valve_sim.core.steady_state import cracking_pressure, steady_state


def circle_and_line(x):
    """x0^2 + x1^2 = 4 and x0 = x1: roots at +-(sqrt 2, sqrt 2)."""
    return np.array([x[0] ** 2 + x[1] ** 2 - 4.0, x[0] - x[1]])


def test_converges_on_a_circle_and_a_line_with_differences_or_an_analytic_jacobian():
    def jacobian(x):
        return np.array([[2.0 * x[0], 2.0 * x[1]], [1.0, -1.0]])

    for given in (None, jacobian):
        result = newton.newton(circle_and_line, [3.0, 1.0], 1e-12, given)
        assert result.converged and result.method == 'newton'
        assert result.x == pytest.approx([np.sqrt(2.0)] * 2, rel=1e-14)
        assert result.residual <= 1e-14 and 0 < result.iterations < 20


def test_the_line_search_brings_a_far_start_home():
    # arctan's full Newton step from 10 overshoots to ever larger |x| (diverges)
    result = newton.newton(lambda x: np.arctan(x), [10.0], 1e-14)
    assert result.converged and abs(result.x[0]) < 1e-14


def test_a_linear_system_is_solved_in_one_step():
    matrix = np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 2.0]])
    wanted = np.array([1.0, -2.0, 0.5])
    result = newton.newton(lambda x: matrix @ (x - wanted), np.zeros(3), 1e-12)
    assert result.converged and result.x == pytest.approx(wanted, rel=1e-12)
    assert result.iterations <= 2  # the second step only confirms the root


def test_an_unsolvable_system_is_reported_not_converged():
    # x^2 + 1 = 0 has no real root: Newton stalls at the minimum of |f|
    result = newton.newton(lambda x: x ** 2 + 1.0, [0.5], 1e-10)
    assert not result.converged and result.residual == pytest.approx(1.0, abs=1e-3)


def test_a_singular_jacobian_stops_newton_without_a_root():
    # both equations the same: the Jacobian is singular everywhere
    result = newton.newton(
        lambda x: np.array([x[0] + x[1] - 1.0, 2.0 * (x[0] + x[1]) + 1.0]), [0.0, 0.0], 1e-10
    )
    assert not result.converged and np.all(np.isfinite(result.x))


def test_find_root_falls_back_to_hybr_when_newton_fails(monkeypatch):
    called = []

    def failing(function, x0, tolerance, jacobian=None):
        called.append('newton')
        return newton.NewtonResult(np.asarray(x0, float), 1.0, 0, False, 'newton')

    monkeypatch.setattr(newton, 'newton', failing)
    result = find_root(circle_and_line, [3.0, 1.0], 1e-12)
    assert called == ['newton'] and result.method == 'hybr' and result.converged
    assert result.x == pytest.approx([np.sqrt(2.0)] * 2, rel=1e-12)


def test_find_root_uses_newton_alone_when_it_converges(monkeypatch):
    def no_hybr(*_):
        raise AssertionError('hybr called although Newton converged')

    monkeypatch.setattr(newton, 'hybr', no_hybr)
    assert find_root(circle_and_line, [3.0, 1.0], 1e-12).method == 'newton'


def test_find_root_reports_an_unsolvable_system_after_both_fail():
    result = find_root(lambda x: x ** 2 + 1.0, [0.5], 1e-10)
    assert not result.converged and result.residual >= 1.0 - 1e-6


def test_the_default_start_is_solved_by_newton_alone(monkeypatch, reference):
    # valve_node's start: the preset's cracking point and the steady state at 5 L/min
    def no_hybr(*_):
        raise AssertionError('hybr (scipy.optimize) called at the default start')

    monkeypatch.setattr(newton, 'hybr', no_hybr)
    assert cracking_pressure(reference) > 0.0
    assert steady_state(reference, 5.0 / 60000.0)[P_S] > cracking_pressure(reference)


def test_the_steady_state_falls_back_to_hybr_and_finds_the_same_state(monkeypatch, reference):
    by_newton = steady_state(reference, 5.0 / 60000.0)

    def failing(function, x0, tolerance, jacobian=None):
        return newton.NewtonResult(np.asarray(x0, float), np.inf, 0, False, 'newton')

    monkeypatch.setattr(newton, 'newton', failing)
    assert steady_state(reference, 5.0 / 60000.0) == pytest.approx(by_newton, rel=1e-12)
