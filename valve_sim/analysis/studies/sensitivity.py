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
Global sensitivity: Sobol first-order and total indices with SALib (Saltelli's design).

The design is drawn in the unit cube (SALib's scrambled Sobol sequence, N base
samples -> N (D + 2) runs, no second-order terms) and mapped through each
parameter's distribution (tolerances.Distribution), so the indices belong to
those distributions; the inverse-CDF map leaves the variance decomposition
unchanged. S_1 is the share of the output variance a parameter explains alone,
S_T the share it takes part in including interactions: S_T - S_1 is the part
that comes from interactions. SALib is imported only when used.
"""

import numpy as np
from valve_sim.core.errors import ParameterError, UndefinedResultError


CONFIDENCE = 0.95
RESAMPLES = 200  # bootstrap resamples for the confidence intervals


def _problem(distributions):
    return {
        'num_vars': len(distributions),
        'names': [d.name for d in distributions],
        'bounds': [[0.0, 1.0]] * len(distributions),
    }


def sobol_design(distributions, base_samples, seed):
    """Parameter values of Saltelli's design, (N (D + 2), D); N must be a power of two."""
    from SALib.sample import sobol

    if base_samples < 2 or base_samples & (base_samples - 1):
        raise ParameterError(f'--samples must be a power of two >= 2, not {base_samples}')
    unit = sobol.sample(_problem(distributions), base_samples, calc_second_order=False, seed=seed)
    return np.column_stack([d.values(unit[:, i]) for i, d in enumerate(distributions)])


def sobol_indices(distributions, outputs, seed):
    """
    S1, S1_conf, ST, ST_conf (arrays, one per parameter) of outputs in design order.

    CONFIDENCE intervals by bootstrap (half-widths), drawn from seed + 1: SALib seeds
    its bootstrap only for a true seed, so seed 0 would draw from numpy's global state
    and give other intervals on every run. outputs must be finite:
    undefined values make the indices undefined and raise UndefinedResultError
    (a ValueError).
    """
    from SALib.analyze import sobol

    outputs = np.asarray(outputs, dtype=float)
    if not np.all(np.isfinite(outputs)):
        raise UndefinedResultError(f'{int(np.sum(~np.isfinite(outputs)))} runs have no value')
    if np.ptp(outputs) == 0.0:
        raise UndefinedResultError('the output is the same in every run')
    result = sobol.analyze(
        _problem(distributions),
        outputs,
        calc_second_order=False,
        num_resamples=RESAMPLES,
        conf_level=CONFIDENCE,
        seed=seed + 1,
    )
    keys = ('S1', 'S1_conf', 'ST', 'ST_conf')
    return {key: np.asarray(result[key], dtype=float) for key in keys}
