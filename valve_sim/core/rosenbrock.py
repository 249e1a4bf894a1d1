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
A stiff-stable step of the valve model: the two-stage Rosenbrock method ROS2.

RK4 is stable only while step * rate stays below 2.79 for the fastest decay rate of
the model's Jacobian. A chamber of a few mm^3 between wide orifices relaxes at 1e8 to
1e10 1/s: RK4 would need sub-steps of nanoseconds, and a valve that hunts drives
its chamber there mid-run. Such a chamber is quasi-static on any step the tools
take; an L-stable method follows it there at any step size. ROS2 (Verwer, Spee,
Blom and Hundsdorfer, SIAM J. Sci. Comput. 20 (1999) 1456-1480) is second order and
L-stable, with gamma = 1 + 1/sqrt(2):

    (I - gamma h J) k1 = f(y)
    (I - gamma h J) k2 = f(y + h k1) - 2 k1
    y' = y + 3/2 h k1 + 1/2 h k2

with J the Jacobian of f at y, by forward differences here. The integrator takes it
only where RK4 would need more sub-steps than it allows (integrator.split_step),
with its own error control (step doubling, the same tolerance): at every operating
point RK4 handles, no result changes.

The state is solved for in scaled units (pressures by burst_pressure, positions and
velocities by their stroke), so that the 8 x 8 system is well scaled for Gaussian
elimination with partial pivoting.
"""

import math

import numpy as np
from valve_sim.core.jit import jit
from valve_sim.core.model import derivatives, X, X_DOT, Y, Y_DOT


GAMMA = 1.0 + 1.0 / math.sqrt(2.0)
# Forward-difference step of the Jacobian: this share of a state's magnitude, or of its
# scale (burst_pressure, the stroke, the stroke per millisecond) near zero.
DIFFERENCE_SHARE = 1.5e-8
VELOCITY_TIME = 1e-3  # [s]: a velocity's scale is its stroke per this time


@jit
def state_scales(c):
    """Return each state's scale (pressures, positions, velocities) as an 8-array."""
    scales = np.full(8, c.burst_pressure)
    scales[X], scales[X_DOT] = c.main_valve_stroke, c.main_valve_stroke / VELOCITY_TIME
    scales[Y], scales[Y_DOT] = c.poppet_stroke, c.poppet_stroke / VELOCITY_TIME
    return scales


@jit
def solve_in_place(matrix, right_sides):
    """Solve matrix @ x = b for each column b of right_sides in place (destroys the matrix)."""
    n = matrix.shape[0]
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(matrix[row, col]) > abs(matrix[pivot, col]):
                pivot = row
        if pivot != col:
            for j in range(n):
                matrix[col, j], matrix[pivot, j] = matrix[pivot, j], matrix[col, j]
            for j in range(right_sides.shape[1]):
                right_sides[col, j], right_sides[pivot, j] = (
                    right_sides[pivot, j], right_sides[col, j]
                )
        for row in range(col + 1, n):
            factor = matrix[row, col] / matrix[col, col]
            for j in range(col, n):
                matrix[row, j] -= factor * matrix[col, j]
            for j in range(right_sides.shape[1]):
                right_sides[row, j] -= factor * right_sides[col, j]
    for col in range(n - 1, -1, -1):
        for j in range(right_sides.shape[1]):
            total = right_sides[col, j]
            for k in range(col + 1, n):
                total -= matrix[col, k] * right_sides[k, j]
            right_sides[col, j] = total / matrix[col, col]


@jit
def ros2_step(state, q, p_t, c, h):
    """
    Return the state (an 8-array) after one ROS2 step of size h [s], inputs held.

    q: inlet flow [m^3/s]; p_t: tank pressure [Pa, gauge]. The stages' second right-hand
    side is formed after the first is solved, so both share the one elimination: the
    system is solved twice, the Jacobian taken once.
    """
    scales = state_scales(c)
    origin = np.empty(8)
    for i in range(8):
        origin[i] = state[i]
    rate = np.empty(8)
    jacobian = np.empty((8, 8))  # in scaled units: d(f_i / s_i) / d(y_j / s_j)
    point = origin.copy()
    # One call site of derivatives (inlined): the rate at the state, then each column.
    for column in range(-1, 8):
        if column >= 0:
            delta = DIFFERENCE_SHARE * max(abs(origin[column]), scales[column])
            point[column] = origin[column] + delta
        evaluated = derivatives(point, q, c, p_t)
        for i in range(8):
            if column < 0:
                rate[i] = evaluated[i]
            else:
                jacobian[i, column] = (
                    (evaluated[i] - rate[i]) / delta * scales[column] / scales[i]
                )
        if column >= 0:
            point[column] = origin[column]
    matrix = np.empty((8, 8))
    stages = np.empty((8, 2))
    for stage in range(2):
        for i in range(8):
            for j in range(8):
                matrix[i, j] = (1.0 if i == j else 0.0) - GAMMA * h * jacobian[i, j]
        if stage == 0:
            for i in range(8):
                stages[i, 0] = rate[i] / scales[i]
                stages[i, 1] = 0.0
        else:
            for i in range(8):
                point[i] = origin[i] + h * stages[i, 0] * scales[i]
            evaluated = derivatives(point, q, c, p_t)
            for i in range(8):
                stages[i, 1] = evaluated[i] / scales[i] - 2.0 * stages[i, 0]
        solve_in_place(matrix, stages[:, stage:stage + 1])
    reached = np.empty(8)
    for i in range(8):
        reached[i] = origin[i] + h * (1.5 * stages[i, 0] + 0.5 * stages[i, 1]) * scales[i]
    return reached
