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
The uncertainty of a calibration: 95 % intervals and correlations from the Jacobian.

central_jacobian() differentiates the fit's residuals at its result (normalised
units u = value / start); add_uncertainty() turns that Jacobian J into approximate
95 % intervals and correlations: covariance s^2 (J^T J)^-1, s^2 = residual variance
for a recording, 1 for measures (their residuals are in units of their tolerance),
none of either when the target determines fewer combinations of the fitted
parameters (the rank of J) than there are parameters. calibration.calibrate() calls both.
"""

import numpy as np


RANK_TOLERANCE = 1e-6  # singular values of the Jacobian below this (relative) count as 0
Z_95 = 1.959964  # two-sided 95 % quantile of the normal distribution


def central_jacobian(residuals, u, relative_step):
    """Return residuals(u) and the central-difference Jacobian d(residuals)/du at u."""
    base = residuals(u)
    columns = []
    for j in range(len(u)):
        step = relative_step * max(abs(u[j]), 1e-3)
        up, down = u.copy(), u.copy()
        up[j] += step
        down[j] -= step
        columns.append((residuals(up) - residuals(down)) / (2.0 * step))
    return base, np.column_stack(columns)


def add_uncertainty(result, target, jacobian, start):
    """
    Set result's approximate 95 % intervals and correlations from the Jacobian (normalised u).

    None of either when the Jacobian's rank (singular values above RANK_TOLERANCE of
    the largest) is below the number of fitted parameters: the target then pins only
    result.rank combinations of them (more parameters than measures), not each value.
    """
    count, fitted = len(result.residuals), len(result.fitted)
    singular = np.linalg.svd(jacobian, compute_uv=False)
    result.rank = int(np.sum(singular > RANK_TOLERANCE * singular[0])) if singular[0] > 0 else 0
    if result.rank < fitted:
        result.uncertainty_note = (
            f'no intervals: the target determines {result.rank} combinations of the '
            f'{fitted} fitted parameters, not each of them'
        )
        return
    scale = target.covariance_scale(result.cost, count, fitted)
    information = jacobian.T @ jacobian
    try:
        covariance = scale * np.linalg.inv(information)
    except np.linalg.LinAlgError:
        result.flat = [p.name for p in result.fitted]
        return
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    if not np.all(sigma > 0.0):
        result.uncertainty_note = (
            'no intervals or correlations: the residual is zero (a perfect fit, as of a '
            'noise-free recording of this very model), so the data tell nothing of their '
            'noise, and an uncertainty computed from them would be zero'
        )
        return
    result.intervals = [
        (value - Z_95 * s * scale_, value + Z_95 * s * scale_)
        for value, s, scale_ in zip(result.values, sigma, start)
    ]
    with np.errstate(invalid='ignore', divide='ignore'):
        result.correlations = covariance / np.outer(sigma, sigma)
