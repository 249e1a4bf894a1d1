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
Manufacturing tolerances: parameter distributions, sampling, limits, yield.

A variation is NAME=SPEC (NAME: ROS name or paper symbol; values in SI units):
  NAME=+-X%  or  NAME=±X%   uniform on nominal * (1 -+ X/100)
  NAME=±Xum  (or mm)        uniform on nominal -+ X, for a length: a machine shop's
                            tolerance (um, µm and mm; the parameter's unit must be m)
  NAME=LO:HI                uniform on [LO, HI]
  NAME=MEAN~N(S%)           normal, mean MEAN, sigma S % of MEAN (MEAN may be
  NAME=MEAN~N(S)            left out: the nominal value); sigma S in SI units
Samples are drawn in the unit cube (scipy.stats.qmc Latin hypercube or scrambled
Sobol, or pseudo-random) and mapped through each distribution's inverse CDF, so
the same seed gives the same samples everywhere. A limit is MEASURE<=VALUE (or
<, >=, >) on one of the six measures; a valve passes when every limit holds, and
a measure that does not exist (or a run that failed) fails its limits.
"""

from collections import Counter
import csv
from dataclasses import dataclass
import math
import re

import numpy as np
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.core.errors import ParameterError
from valve_sim.core.output_files import replacing
from valve_sim.core.parameters import resolve_name, SPECS

# scipy.stats is imported in the functions that use it, so that `valve-sim tolerance
# --help` (its parser takes SAMPLERS from here) stays quick.


SAMPLERS = ('lhs', 'sobol', 'random')
PERCENTILES = (1, 5, 50, 95, 99)
CONFIDENCE = 0.95
_NUMBER = r'[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?'
_PLUS_MINUS = re.compile(rf'^(?:±|\+-|\+/-)\s*({_NUMBER})\s*%$')
_PLUS_MINUS_LENGTH = re.compile(rf'^(?:±|\+-|\+/-)\s*({_NUMBER})\s*(um|µm|μm|mm)$')
LENGTH_UNITS = {'um': 1e-6, 'µm': 1e-6, 'μm': 1e-6, 'mm': 1e-3}  # to m
_RANGE = re.compile(rf'^({_NUMBER})\s*:\s*({_NUMBER})$')
_NORMAL = re.compile(rf'^({_NUMBER})?\s*~\s*N\(\s*({_NUMBER})\s*(%?)\s*\)$')
_LIMIT = re.compile(rf'^\s*(\w+)\s*(<=|>=|<|>)\s*({_NUMBER})\s*$')


@dataclass(frozen=True)
class Distribution:
    """One varied parameter: uniform on [a, b] or normal with mean a and sigma b (SI)."""

    name: str
    kind: str
    a: float
    b: float
    text: str

    def values(self, unit):
        """Return the parameter values of points of the unit interval (inverse CDF)."""
        unit = np.clip(np.asarray(unit, dtype=float), 1e-12, 1.0 - 1e-12)
        if self.kind == 'uniform':
            return self.a + unit * (self.b - self.a)
        from scipy import stats

        return stats.norm.ppf(unit, loc=self.a, scale=self.b)

    def describe(self):
        """JSON-ready statement of the distribution, in SI units."""
        spec = SPECS[self.name]
        shape = (
            {'low': self.a, 'high': self.b}
            if self.kind == 'uniform'
            else {'mean': self.a, 'sigma': self.b}
        )
        return {
            'parameter': self.name,
            'symbol': spec.symbol,
            'unit': spec.unit,
            'distribution': self.kind,
            **shape,
            'given_as': self.text,
        }


def _half_width(number, text):
    """Return the X of ±X: a size, never negative (±-1% is no tolerance); ParameterError."""
    if float(number) < 0.0:
        raise ParameterError(f'variation {text!r}: the X of ±X must be >= 0, got {number}')
    return float(number)


def parse_variation(text, params):
    """One NAME=SPEC into a Distribution around params' nominal value; ParameterError if bad."""
    name, separator, spec = text.partition('=')
    if not separator:
        raise ParameterError(f'variation {text!r}: expected NAME=SPEC, e.g. d_c=±2%')
    name, spec = resolve_name(name.strip()), spec.strip()
    nominal = params[name]
    if match := _PLUS_MINUS.match(spec):
        half = _half_width(match[1], text) / 100.0 * abs(nominal)
        distribution = Distribution(name, 'uniform', nominal - half, nominal + half, text)
    elif match := _PLUS_MINUS_LENGTH.match(spec):
        if SPECS[name].unit != 'm':
            raise ParameterError(
                f'variation {text!r}: {match[2]} is a length, and {name} is in {SPECS[name].unit}'
            )
        half = _half_width(match[1], text) * LENGTH_UNITS[match[2]]
        distribution = Distribution(name, 'uniform', nominal - half, nominal + half, text)
    elif match := _RANGE.match(spec):
        distribution = Distribution(name, 'uniform', float(match[1]), float(match[2]), text)
    elif match := _NORMAL.match(spec):
        mean = float(match[1]) if match[1] else nominal
        sigma = float(match[2]) * (abs(mean) / 100.0 if match[3] else 1.0)
        distribution = Distribution(name, 'normal', mean, sigma, text)
    else:
        raise ParameterError(
            f'variation {text!r}: SPEC must be ±X%, ±Xum (or mm), LO:HI, MEAN~N(S%) or '
            'MEAN~N(S)'
        )
    if not (math.isfinite(distribution.a) and math.isfinite(distribution.b)):
        raise ParameterError(f'variation {text!r}: values must be finite')
    if distribution.kind == 'uniform' and not distribution.a < distribution.b:
        raise ParameterError(f'variation {text!r}: the range must have LO < HI')
    if distribution.kind == 'normal' and not distribution.b > 0.0:
        raise ParameterError(f'variation {text!r}: sigma must be > 0')
    _check_within_limits(distribution, text)
    return distribution


def _check_within_limits(distribution, text):
    """
    Refuse a variation that leaves the parameter's limits (SPECS).

    A valve beyond them cannot be set. Uniform: [a, b] within the limits; normal: the
    mean within them and sigma at most their span (the tails beyond are drawn, and
    fail as runs that cannot be set).
    """
    spec, a, b = SPECS[distribution.name], distribution.a, distribution.b
    limits = (
        f'the limits of {distribution.name} ({spec.symbol}), [{spec.minimum:g}, '
        f'{spec.maximum:g}] {spec.unit}'
    )
    if distribution.kind == 'uniform' and not spec.minimum <= a < b <= spec.maximum:
        raise ParameterError(f'variation {text!r}: values {a:g}:{b:g} {spec.unit} leave {limits}')
    if distribution.kind == 'normal' and not (
        spec.minimum <= a <= spec.maximum and b <= spec.maximum - spec.minimum
    ):
        raise ParameterError(
            f'variation {text!r}: mean {a:g} {spec.unit}, sigma {b:g} {spec.unit} leave {limits}'
        )


def follows_nominal(text):
    """Whether a variation NAME=SPEC is stated about the nominal value (±, or ~N without MEAN)."""
    spec = text.partition('=')[2].strip()
    normal = _NORMAL.match(spec)
    return bool(
        _PLUS_MINUS.match(spec) or _PLUS_MINUS_LENGTH.match(spec) or (normal and not normal[1])
    )


def parse_variations(texts, params):
    """Comma-separated NAME=SPEC lists (one or several texts) into Distributions."""
    distributions = [
        parse_variation(item.strip(), params)
        for text in texts
        for item in text.split(',')
        if item.strip()
    ]
    names = [d.name for d in distributions]
    if not names:
        raise ParameterError('no parameter to vary: give --vary NAME=SPEC[,NAME=SPEC...]')
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ParameterError(f'parameter(s) varied twice: {", ".join(repeated)}')
    return distributions


def unit_samples(count, dimensions, seed, sampler='lhs'):
    """Points in the unit cube, (count, dimensions); the same seed gives the same points."""
    if count < 1:
        raise ParameterError('--samples must be at least 1')
    from scipy.stats import qmc

    if sampler == 'lhs':
        return qmc.LatinHypercube(d=dimensions, seed=seed).random(count)
    if sampler == 'sobol':
        if count & (count - 1):
            raise ParameterError(f'the Sobol sampler needs a power of two samples, not {count}')
        sobol = qmc.Sobol(d=dimensions, scramble=True, seed=seed)
        return sobol.random_base2(count.bit_length() - 1)
    if sampler == 'random':
        return np.random.default_rng(seed).random((count, dimensions))
    raise ParameterError(f'unknown sampler {sampler!r}; known: {", ".join(SAMPLERS)}')


def draw(distributions, count, seed, sampler='lhs'):
    """Draw parameter values, (count, len(distributions)), SI units."""
    unit = unit_samples(count, len(distributions), seed, sampler)
    return np.column_stack([d.values(unit[:, i]) for i, d in enumerate(distributions)])


@dataclass(frozen=True)
class Limit:
    """A specification limit on one measure, e.g. P_1_percent <= 4."""

    measure: str
    operator: str
    value: float

    def holds(self, measures):
        """Whether the measure exists and meets the limit."""
        value = measures.get(self.measure)
        if value is None:
            return False
        return {
            '<=': value <= self.value,
            '<': value < self.value,
            '>=': value >= self.value,
            '>': value > self.value,
        }[self.operator]

    def __str__(self):
        return f'{self.measure}{self.operator}{self.value:g}'


def parse_limits(text):
    """'P_1_percent<=4,T_s_ms<=600' into Limits; ParameterError names a bad one."""
    limits = []
    for item in (text or '').split(','):
        if not item.strip():
            continue
        match = _LIMIT.match(item)
        if not match or match[1] not in MEASURE_NAMES or not math.isfinite(float(match[3])):
            raise ParameterError(
                f'limit {item.strip()!r}: expected MEASURE<=VALUE (or <, >=, >) with MEASURE '
                f'one of {", ".join(MEASURE_NAMES)}'
            )
        limits.append(Limit(match[1], match[2], float(match[3])))
    return limits


def passes(row, limits):
    """Whether a runner row (measures, error) meets every limit."""
    return row['error'] is None and all(limit.holds(row['measures']) for limit in limits)


def yield_interval(passed, total, confidence=CONFIDENCE):
    """Clopper-Pearson interval of the pass fraction (samples taken as independent)."""
    from scipy import stats

    interval = stats.binomtest(passed, total).proportion_ci(confidence, method='exact')
    return [float(interval.low), float(interval.high)]


def undefined_reasons(rows, name):
    """
    Why rows have no value of measure name: {reason: count}, commonest first.

    The reason is the run's error where it failed, else the measure's own reason
    (e.g. no second overshoot).
    """
    reasons = Counter(
        row['error'] or row['reasons'].get(name, 'no reason recorded')
        for row in rows
        if row['measures'][name] is None
    )
    return dict(reasons.most_common())


def summarise(rows, limits):
    """Yield with its interval, failures per limit, percentiles and undefined reasons."""
    total = len(rows)
    passed = sum(passes(row, limits) for row in rows)
    failed_runs = [row for row in rows if row['error'] is not None]
    percentiles = {}
    for name in MEASURE_NAMES:
        values = np.array([row['measures'][name] for row in rows if row['measures'][name]
                           is not None], dtype=float)
        entry = {'defined': int(values.size), 'undefined': total - int(values.size)}
        if entry['undefined']:
            entry['undefined_reasons'] = undefined_reasons(rows, name)
        if values.size:
            entry.update(
                {f'p{p}': float(np.percentile(values, p)) for p in PERCENTILES},
                mean=float(values.mean()),
                min=float(values.min()),
                max=float(values.max()),
            )
        percentiles[name] = entry
    return {
        'yield': {
            'passed': int(passed),
            'total': total,
            'fraction': passed / total if total else None,
            f'ci{int(CONFIDENCE * 100)}': yield_interval(passed, total) if total else None,
            'interval_method': 'Clopper-Pearson exact binomial, samples taken as independent '
            '(conservative for quasi-random samples)',
        },
        'limits': [str(limit) for limit in limits],
        'failures': {
            **{
                str(limit): sum(
                    1 for row in rows if row['error'] is None and not limit.holds(row['measures'])
                )
                for limit in limits
            },
            'run failed': len(failed_runs),
        },
        'percentiles': percentiles,
    }


def write_samples(path, names, values, rows, limits):
    """samples.csv: per sampled valve its values, preload, measures, pass and reasons."""
    with replacing(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(
            ['index', *names, 'pilot_spring_preload', *MEASURE_NAMES, 'pass', 'reasons', 'error']
        )
        for index, sample in enumerate(values):
            row = rows[index]
            writer.writerow(
                [
                    index,
                    *(repr(float(v)) for v in sample),
                    row.get('pilot_spring_preload', ''),
                    *('' if row['measures'][n] is None else row['measures'][n]
                      for n in MEASURE_NAMES),
                    int(passes(row, limits)),
                    '; '.join(f'{n}: {r}' for n, r in row['reasons'].items()),
                    row['error'] or '',
                ]
            )
