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
Robust design optimisation: the best valve within bounds whose machined batch meets the spec.

NSGA-II (pymoo) over the designed parameters (--design); each candidate's nominal
measures are the objectives (--minimise, --maximise), and its yield, the share of
valves made within --tolerance that meet --limits (and whose modes decay), comes from
a quasi-random Monte Carlo on the Dask runner, sampled in rounds and stopped once
decided (--sequential, analysis.design.sequential_yield; a candidate still undecided
after --defer-after valves is left open, and run on only if the Pareto set needs it;
--budget caps the runs). The
Pareto designs and the baselines (the reference valve, Table 2) are then confirmed
with more, independent samples. See valve_sim.analysis.design.optimisation. Writes into --out:
  evaluations/     the runner's results, one file per generation (--resume)
  pareto.csv       each Pareto design: values, nominal measures, both yields
  pareto.json      the problem, the Pareto set, the baselines, the chosen design
                   against Table 2 measure by measure
  params/          a parameter file per Pareto design and baseline
  pareto_front.png, distributions.png (the chosen design's measures against
                   Table 2's under the same tolerances)
"""

from argparse import ArgumentTypeError
from pathlib import Path
import sys

from valve_sim.analysis.design.robust_yield import MIN_DECAY_RATE
from valve_sim.analysis.design.sequential_yield import DEFER_AFTER, FIRST_ROUND, STOP_ALPHA
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.analysis.studies.backend import check_fits, MAX_RUNS, open_backend
from valve_sim.analysis.studies.cases import preset_protocol
from valve_sim.analysis.studies.tolerances import parse_limits, SAMPLERS
from valve_sim.commands.options import (
    add_options,
    add_protocol_arguments,
    add_runner_arguments,
    load_from_arguments,
    number,
)
from valve_sim.core.errors import StudyError
from valve_sim.core.extras import require
from valve_sim.core.input_files import size_text
from valve_sim.core.output_files import make_folder

# The optimiser and the model (pymoo, numba, scipy) are imported in the functions that run
# them, so that `valve-sim optimise --help` stays quick.

# [bytes] a sampled valve's run on the worker that evaluates its candidate: every valve of
# a candidate runs in one batch, waveforms and all; 1.1-1.5 MiB measured (tracemalloc
# peak of studies.runner.evaluate_batch over 32-128 valves of the step test), rounded up
BYTES_PER_VALVE = 2 * 1024 * 1024
MAX_CANDIDATES = 100_000  # population x generations: the rows kept for the Pareto set
# [bytes] a candidate's row kept in the client (2.4 KiB as JSON), with Python's overhead
BYTES_PER_CANDIDATE = 16 * 1024
MAX_POPULATION = 10_000
MAX_GENERATIONS = 10_000


def number_or_off(text, accepts, bounds):
    """Return the number in text if accepts(value), None for off; else ArgumentTypeError."""
    if text.strip().lower() == 'off':
        return None
    try:
        value = float(text)
    except ValueError:
        value = float('nan')
    if not accepts(value):
        raise ArgumentTypeError(f'must be {bounds}; got {text!r}')
    return value


def decay_rate_value(text):
    """'3' -> 3.0 [1/s]; 'off' -> None (argparse type)."""
    return number_or_off(text, lambda value: 0.0 <= value <= MAX_DECAY_RATE,
                         f'a rate {decay_rate_value.bounds}')


# [1/s] a mode decaying by e in 1 us: faster than the model's steps (10 us) resolve
MAX_DECAY_RATE = 1e6
decay_rate_value.bounds = f'in [0, {MAX_DECAY_RATE:g}] 1/s, or off'


def alpha_value(text):
    """'0.05' -> 0.05, within (0, 1); 'off' -> None (argparse type)."""
    return number_or_off(text, lambda value: 0.0 < value < 1.0, 'a chance in (0, 1), or off')


def defer_value(text):
    """'64' -> 64 valves; 'off' -> None (argparse type)."""
    value = number_or_off(text, lambda value: 1 <= value <= MAX_RUNS and value == int(value),
                          f'a whole number of valves, 1 to {MAX_RUNS:,}, or off')
    return None if value is None else int(value)


def add_arguments(parser):
    add_options(parser, '--params', '--set', '--preset-pressure', '--out')
    parser.add_argument('--design', action='append', required=True, metavar='NAME=LO:HI,...',
                        help='designed parameters and their bounds: NAME=LO:HI (SI) or NAME=±X%% '
                        '(of the nominal value); repeatable')
    parser.add_argument('--minimise', action='append', metavar='MEASURE,...',
                        help='measures of the nominal valve to minimise, e.g. P_1_percent,T_s_ms')
    parser.add_argument('--maximise', action='append', metavar='MEASURE,...',
                        help='measures of the nominal valve to maximise')
    parser.add_argument('--limits', metavar='SPEC', default='',
                        help='what every valve must meet, e.g. "r_d<=0.85,P_o_percent<=0.2" '
                        '(as for tolerance)')
    parser.add_argument('--tolerance', action='append', required=True, metavar='NAME=SPEC,...',
                        help='machining tolerances about each design, as tolerance --vary: '
                        'NAME=±X%%, NAME=±Xum (or mm: a length), NAME=~N(S%%), NAME=~N(S); '
                        'LO:HI only for a parameter not designed; repeatable')
    parser.add_argument('--yield', dest='required_yield', default='0.99', metavar='FRACTION',
                        help='required share of valves meeting the limits (default 0.99; '
                        '99%% works too)')
    stability = ("every valve's slowest linear mode must decay at R [1/s] at 5 and 20 L/min "
                 f'(default {MIN_DECAY_RATE:g}: 95 %% within the 1 s window); off: not asked')
    parser.add_argument('--min-decay-rate', type=decay_rate_value, default=MIN_DECAY_RATE,
                        metavar='R', help=stability)
    parser.add_argument('--samples', type=number('a sample count', '', 1, MAX_RUNS, integer=True),
                        default=256, metavar='N',
                        help='Monte Carlo valves per candidate, run together on one worker '
                        f'({size_text(BYTES_PER_VALVE)} of memory each; default 256)')
    parser.add_argument('--sequential', type=alpha_value, default=STOP_ALPHA, metavar='ALPHA',
                        help="sample each candidate's valves in rounds (prefixes of the same "
                        'draw) and stop once its yield is decided against --yield, each wrong '
                        f'way with chance at most ALPHA/2 (default {STOP_ALPHA:g}); a nominal '
                        'valve out of spec takes no samples; off: every candidate its full '
                        'sample')
    parser.add_argument('--first-round', default=FIRST_ROUND, metavar='N',
                        type=number('a sample count', '', 1, MAX_RUNS, integer=True),
                        help=f'valves in the first round, doubling after (default {FIRST_ROUND})')
    parser.add_argument('--defer-after', type=defer_value, default=DEFER_AFTER, metavar='N',
                        help='with --sequential: a candidate still undecided after the round '
                        'that reaches N valves is left open, ranked on its estimate; the open '
                        'candidates the Pareto set needs run on to a verdict at the end '
                        f"(default {DEFER_AFTER}; off: every candidate's rule to a verdict)")
    parser.add_argument('--budget', default=None, metavar='RUNS',
                        type=number('a run budget', '', 1, 10**12, integer=True),
                        help='runs the search may spend: no generation starts that would pass '
                        'it, judged by the last one (default: --generations decides)')
    parser.add_argument('--confirm-samples', default=1024, metavar='N',
                        type=number('a sample count', '', 0, MAX_RUNS, integer=True),
                        help='valves per Pareto design and baseline in the confirmation, with '
                        'the next seed (default 1024; 0: no confirmation)')
    parser.add_argument('--sampler', choices=SAMPLERS, default='sobol',
                        help='sobol: scrambled Sobol, N a power of two (default); lhs: Latin '
                        'hypercube; random: pseudo-random (all seeded)')
    parser.add_argument('--population', default=24, metavar='N',
                        type=number('a population', '', 2, MAX_POPULATION, integer=True),
                        help='candidates per generation (default 24)')
    parser.add_argument('--generations', default=20, metavar='N',
                        type=number('a generation count', '', 1, MAX_GENERATIONS, integer=True),
                        help='generations, the first one a Latin hypercube (default 20; '
                        f'population x generations at most {MAX_CANDIDATES:,} candidates)')
    add_options(parser, '--seed', help='seed of the optimiser and the samples (default 0)')
    add_options(parser, '--step-size')
    add_protocol_arguments(parser)
    add_runner_arguments(parser)


def problem_from(args):
    """Return (RobustProblem, the protocol's statement) from the options."""
    from valve_sim.analysis.design.optimisation import (
        exact_text,
        parse_design,
        parse_fraction,
        parse_objectives,
        parse_tolerances,
        RobustProblem,
    )

    loaded = load_from_arguments(args)
    params, settings = loaded.params, loaded.settings
    design = parse_design(args.design, params, args.protocol)
    preset, protocol = preset_protocol(args.protocol, params)
    problem = RobustProblem(
        params=params,
        design=tuple(design),
        objectives=tuple(parse_objectives(args.minimise, args.maximise)),
        limits=tuple(exact_text(limit) for limit in parse_limits(args.limits)),
        tolerances=tuple(parse_tolerances(args.tolerance, params, design)),
        required_yield=parse_fraction(args.required_yield, '--yield'),
        preset_pressure=preset,
        protocol=args.protocol,
        samples=args.samples,
        sampler=args.sampler,
        seed=args.seed,
        confirm_samples=args.confirm_samples,
        stop_alpha=args.sequential,
        first_round=args.first_round,
        defer_after=args.defer_after,
        min_decay_rate=args.min_decay_rate,
        step_size=settings['step_size'],
    )
    return problem.check(), protocol


def print_outcome(problem, summary):
    """Print the Pareto set, then the chosen design against Table 2, measure by measure."""
    names = [bound.name for bound in problem.design]
    objectives = [o.measure for o in problem.objectives]
    undecided = summary['candidates_undecided']
    print(f"{summary['candidates_evaluated']} candidates, {summary['candidates_feasible']} "
          'meet the limits and the yield'
          + (f', {undecided} left with it undecided (the Pareto set does not need them)'
             if undecided else '') + f"; Pareto set of {len(summary['pareto'])}:")
    print(f'{"design":<15}' + ''.join(f'{n[:13]:>14}' for n in names + objectives)
          + f'{"yield (95 % interval)":>28}')
    for entry in summary['pareto']:
        result = entry['confirmed_yield'] or entry['search_yield']
        cells = [entry['design'][n] for n in names] + [
            entry['nominal_measures'][m] for m in objectives]
        mark = ' *' if entry['chosen'] else ''
        print(f"{entry['label']:<15}" + ''.join(f'{v:>14.5g}' for v in cells)
              + f'{_yield_text(result):>28}{mark}')
    if not summary['pareto']:
        print('no candidate meets the limits and the required yield: loosen --limits or '
              '--yield, or widen --design')
        return
    if summary['chosen'] is None:
        print('no Pareto design meets the required yield on confirmation')
        return
    versus = summary.get('chosen_against_table2')
    if not versus:
        return
    chosen = next(e for e in summary['pareto'] if e['chosen'])
    table2 = summary['baselines']['table2']
    print(f"\n{summary['chosen']} (*) against Table 2, nominal valves:")
    print(f'{"measure":<14}{"chosen":>12}{"Table 2":>12}{"change":>10}')
    for name in MEASURE_NAMES:
        row = versus[name]
        cells = ''.join('{:>12}'.format('-' if row[k] is None else f'{row[k]:.4g}')
                        for k in ('chosen', 'table2'))
        change = '-' if row['change_percent'] is None else f"{row['change_percent']:+.1f} %"
        print(f'{name:<14}{cells}{change:>10}')
    for label, entry in (('chosen', chosen), ('Table 2', table2)):
        result = entry['confirmed_yield'] or entry['search_yield']
        print(f'yield of {label}: {_yield_text(result)} over {result["samples"]} valves')


def check_sizes(args):
    """Raise StudyError unless a candidate's valves fit a worker and the candidates the client."""
    valves = max(args.samples, args.confirm_samples) + 1  # the sampled valves and the nominal
    which = '--samples' if args.samples >= args.confirm_samples else '--confirm-samples'
    check_fits(f'{which} {valves - 1}', valves, 'valves run together on one worker', MAX_RUNS,
               BYTES_PER_VALVE)
    check_fits(f'--population {args.population} x --generations {args.generations}',
               args.population * args.generations, 'candidates', MAX_CANDIDATES,
               BYTES_PER_CANDIDATE)


def _yield_text(result):
    low, high = result['ci95']
    return f"{100 * result['fraction']:.1f} % ({100 * low:.1f}-{100 * high:.1f})"


def run(args):
    from valve_sim.analysis.design.optimisation import outcome_of, search
    from valve_sim.analysis.design.plots import plot_distributions, plot_pareto_front
    from valve_sim.analysis.design.report import write_outputs

    require('optimise', 'studies', 'pymoo', error=StudyError)
    problem, protocol = problem_from(args)
    check_sizes(args)
    out = make_folder(Path(args.out), subfolders=('evaluations', 'params'))  # links not followed
    runs = args.population * args.generations * (problem.samples + 1)
    sampling = ('each' if problem.stop_alpha is None else
                f'at most each, in rounds from {min(problem.first_round, problem.samples)} '
                f'(sequential, alpha {problem.stop_alpha:g})')
    budget = '' if args.budget is None else f', budget {args.budget:,} runs'
    print(
        f"optimise: protocol {protocol['protocol']}, preset "
        f"{protocol['preset_pressure'] / 1e6:.4f} MPa; {args.generations} generations of "
        f'{args.population} candidates, {problem.samples} valves {sampling} ({runs:,} runs '
        f'with full samples{budget}), then the Pareto set and 2 baselines with '
        f'{problem.confirm_samples} valves each',
        file=sys.stderr,
    )
    backend = open_backend('optimise', args.scheduler, args.workers, args.dashboard)
    try:
        records = search(problem, backend, out / 'evaluations', args.population,
                         args.generations, args.resume, batch_size=args.batch_size or 1,
                         budget=args.budget)
        outcome = outcome_of(problem, records, backend, out / 'evaluations', args.resume,
                             batch_size=args.batch_size or 1)
    finally:
        backend.close()
    summary = write_outputs(out, problem, outcome, records, args.population, args.generations)
    plot_pareto_front(out / 'pareto_front.png', problem, records, outcome)
    if outcome['chosen'] is not None and 'table2' in outcome['baselines']:
        plot_distributions(out / 'distributions.png', problem, [
            (summary['chosen'], outcome['pareto'][outcome['chosen']][2]),
            ('Table 2', outcome['baselines']['table2']),
        ])
    print_outcome(problem, summary)
    search, confirmation = summary['runs']['search'], summary['runs']['confirmation']
    resolution = search['resolution']
    print(f"runs: search {search['runs']:,} ({search['saved']:,} saved against full samples: "
          f"{100 * search['runs'] / max(1, search['full_sample_runs']):.0f} %; of them "
          f"{resolution['runs']:,} resolving {resolution['candidates']} open candidates of the "
          f"Pareto set), confirmation {confirmation['runs']:,} ({confirmation['designs']} "
          'designs)')
    print(f'wrote {out}/pareto.csv, {out}/pareto.json, {out}/params/ and figures')
    return 0 if summary['chosen'] is not None else 1
