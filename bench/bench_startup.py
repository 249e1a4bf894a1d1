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
Benchmark valve_node's start-up after a colcon build, warm and cold, beside a bare node's.

Over 400 lines: the build, the kinds of start, the baseline checkout and the phase
probe are one run, side by side, so that load from other work spreads over all.
"""

# The summary line above is also this script's --help description.
#
#     python bench/bench_startup.py [--warm 5] [--cold 1] [--json out/bench_startup.json]
#                                   [--baseline /path/to/other/checkout] [--phases 3]
#
# Measures, in one run on a ROS domain of its own (localhost only), the time from
# starting a node process to receiving its first supply_pressure message here:
#
# - bare: a minimal rclpy node (python -c ...) that publishes FluidPressure at 1 kHz,
#   the floor that Python, rclpy and DDS discovery alone set on this machine;
# - built: the first start of valve_node as a plain `colcon build` installs it (this
#   checkout built into a temporary workspace, from the installed executable with the
#   environment that sourcing install/setup.bash gives): its kernels were compiled
#   by the build (setup.py, valve_sim.core.precompile); once per run, as it is first;
# - symlinked: the same after `colcon build --symlink-install` (setup.py develop, which
#   compiles the kernels where colcon's build folder links to the sources), into a
#   workspace of its own and an empty numba cache (NUMBA_CACHE_DIR, for the build and
#   the start: the cache beside the sources is the warm one); once per run, second;
# - warm: valve_node of this checkout, its kernels in numba's cache beside the sources
#   (python -m valve_sim.core.precompile fills it first, as `run.py install` does);
# - cold: valve_node of this checkout with an empty kernel cache (NUMBA_CACHE_DIR a new
#   empty folder), which compiles at its start: what a start costs without the build's
#   or run.py's compile;
# - baseline (--baseline DIR): valve_node of another checkout DIR (e.g. main), warm, run
#   with this interpreter; its kernels and byte code are cached in this run's temporary
#   folder (NUMBA_CACHE_DIR, PYTHONPYCACHEPREFIX: nothing is written into DIR), filled by
#   its precompile and one start that is not counted. Its runs join the bare/warm
#   rotation, so a change is measured against the code before it side by side.
#
# --phases N: after those runs, N more warm starts (and N baseline ones) through a probe
# (PHASE_PROBE) that says where a warm start's time goes: imports by package (python -X
# importtime's own times, summed per package: ROS (rclpy and the messages), numba
# (llvmlite included), numpy, scipy, valve_sim, other), the node's steady state and
# kernel load (its "ready" line), the rest of the node's build, and the first state
# (from the node built to its first message here); imports made during the build (numba's
# target set-up loads scipy.linalg, for one) are shown within it. importtime slows imports
# a little, so these starts are not in the figures above.
#
# Nodes run with Python's byte code written and read (PYTHONDONTWRITEBYTECODE dropped),
# as an installed package's is. After one bare start that is not counted (the probe's
# discovery warms up in it) and one warm (and baseline) start that fills the byte-code
# cache, the built and then the symlinked node start first, right after the builds; then
# runs alternate between bare and warm, so load from other work on the machine spreads
# over both; the cold runs come last. The load average at start and end is printed.
# valve_node's own "ready" log line gives the part spent computing the steady state and
# compiling or loading the kernels.
# Targets (issue 29), against the bare node's median in the same run:
#   first start after a plain colcon build <= bare + 2 s (and after a --symlink-install one);
#   warm <= bare + 0.5 s.

import argparse
import json
import os
from pathlib import Path
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time

from valve_sim.ros.isolation import claim_domain


REPO = Path(__file__).resolve().parent.parent
TIMEOUT = 300.0  # [s] for one start-up (a cold compile on a loaded machine)
BUILD_TIMEOUT = 1800.0  # [s] colcon build, the kernels' compile included, on a loaded machine
BARE_NODE = (
    'import rclpy\n'
    'from sensor_msgs.msg import FluidPressure\n'
    'rclpy.init()\n'
    "node = rclpy.create_node('bare')\n"
    "publisher = node.create_publisher(FluidPressure, 'supply_pressure', 1000)\n"
    'node.create_timer(0.001, lambda: publisher.publish(FluidPressure(fluid_pressure=1.0)))\n'
    'try:\n'
    '    rclpy.spin(node)\n'
    'except KeyboardInterrupt:\n'
    '    pass\n'
)
READY = re.compile(r'compiled or loaded in ([0-9.]+) s')
# Starts valve_node as `python -m valve_sim.ros.valve_node_main` does, stamping (time.monotonic,
# one clock for all processes) when its imports are done and its node is built.
PHASE_PROBE = (
    'import sys, time\n'
    'from valve_sim.ros import valve_node, valve_node_main\n'
    "print(f'PHASE imports {time.monotonic()}', file=sys.stderr, flush=True)\n"
    'build = valve_node.ReliefValveNode.__init__\n'
    'def stamped(self, *args, **kwargs):\n'
    "    print(f'PHASE init {time.monotonic()}', file=sys.stderr, flush=True)\n"
    '    build(self, *args, **kwargs)\n'
    "    print(f'PHASE built {time.monotonic()}', file=sys.stderr, flush=True)\n"
    'valve_node.ReliefValveNode.__init__ = stamped\n'
    "sys.argv[0] = 'valve_node'\n"
    'sys.exit(valve_node_main.main())\n'
)
PHASE = re.compile(r'^PHASE (\w+) ([0-9.]+)$', re.M)
IMPORT_TIME = re.compile(r'^import time:\s+(\d+) \|\s+\d+ \|\s+(\S.*)$', re.M)
IMPORT_GROUPS = ('ROS', 'numba', 'numpy', 'scipy', 'valve_sim', 'other')
LATER_IMPORTS = '  of which imports during the build'  # not a phase of its own
TARGETS = {'built': 2.0, 'symlinked': 2.0, 'warm': 0.5}  # [s] above the bare node's median


class FirstMessage:
    """A subscriber here, per namespace: when did the first supply_pressure arrive."""

    def __init__(self):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        rclpy.init()
        self.node = rclpy.create_node('startup_probe')
        self.arrived = {}  # namespace: time.monotonic() of its first message
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        threading.Thread(target=self.executor.spin, daemon=True).start()

    def watch(self, namespace):
        from sensor_msgs.msg import FluidPressure

        def first(_):
            self.arrived.setdefault(namespace, time.monotonic())

        return self.node.create_subscription(
            FluidPressure, f'{namespace}/supply_pressure', first, 10
        )


def colcon_build(workspace, *options, cache=None):
    """
    Build this checkout with `colcon build OPTIONS` in workspace; return (prefix, seconds).

    cache: the numba cache folder (NUMBA_CACHE_DIR) of the build, None for numba's own.
    """
    colcon = Path(sys.executable).parent / 'colcon'
    env = {key: value for key, value in os.environ.items() if key != 'NUMBA_CACHE_DIR'}
    env['PATH'] = f'{colcon.parent}{os.pathsep}{env["PATH"]}'
    if cache is not None:
        env['NUMBA_CACHE_DIR'] = str(cache)
    workspace.mkdir(exist_ok=True)
    started = time.monotonic()
    done = subprocess.run(
        [str(colcon), 'build', '--paths', str(REPO), '--build-base', 'build',
         '--install-base', 'install', *options],
        cwd=workspace, env=env, capture_output=True, text=True, timeout=BUILD_TIMEOUT,
    )
    if done.returncode != 0:
        raise RuntimeError(f'colcon build failed:\n{done.stdout[-3000:]}{done.stderr[-3000:]}')
    return workspace / 'install' / 'valve_sim', time.monotonic() - started


def import_group(module):
    """Which of IMPORT_GROUPS a module's import time counts to."""
    top = module.strip().split('.')[0]
    if top in ('numba', 'llvmlite'):
        return 'numba'
    if top in ('numpy', 'scipy', 'valve_sim'):
        return top
    ros = ('rclpy', 'rpyutils', 'rosidl', 'ament', 'rcl_')
    if top.startswith(ros) or top.endswith(('_msgs', '_interfaces', '_srvs')):
        return 'ROS'
    return 'other'


def phases(log, started, arrived, ready):
    """Where one probed start's seconds went: {phase: s} from its log (PHASE_PROBE)."""
    stamps = {name: float(value) for name, value in PHASE.findall(log)}
    before, after = log.split('PHASE imports', 1)
    spent = {f'import {group}': 0.0 for group in IMPORT_GROUPS}
    for microseconds, module in IMPORT_TIME.findall(before):
        spent[f'import {import_group(module)}'] += int(microseconds) * 1e-6
    imported = stamps['imports'] - started
    spent['interpreter and unlisted'] = imported - sum(spent.values())
    spent['steady state + kernels'] = ready
    spent[LATER_IMPORTS] = sum(int(us) for us, _ in IMPORT_TIME.findall(after)) * 1e-6
    spent['node build, the rest'] = stamps['built'] - stamps['init'] - ready
    spent['rclpy.init and the rest'] = stamps['init'] - stamps['imports']
    spent['first state'] = arrived - stamps['built']
    return spent


def node_command(kind, prefix, baseline=None):
    """Return (command, environment changes) that start a node of kind (prefix: {kind: path})."""
    if kind == 'baseline':
        return [sys.executable, '-m', 'valve_sim.ros.valve_node_main'], baseline_env(baseline)
    if kind == 'bare':
        return [sys.executable, '-c', BARE_NODE], {}
    if kind in ('built', 'symlinked'):  # as `source install/setup.bash`, `ros2 run` start it
        site = next(prefix[kind].glob('lib/python*/site-packages'))
        # --symlink-install: colcon's hook puts its build folder (links to the sources) first
        paths = [prefix[kind].parent.parent / 'build' / 'valve_sim'] if kind == 'symlinked' else []
        return [str(prefix[kind] / 'lib' / 'valve_sim' / 'valve_node')], {
            'AMENT_PREFIX_PATH': str(prefix[kind]),
            'PYTHONPATH': os.pathsep.join(map(str, paths + [site])),
        }
    return [sys.executable, '-m', 'valve_sim.ros.valve_node_main'], {}


def baseline_env(baseline):
    """Return the environment changes that run baseline.tree, caches in baseline.cache."""
    return {
        'PYTHONPATH': os.pathsep.join([str(baseline.tree), os.environ.get('PYTHONPATH', '')]),
        'NUMBA_CACHE_DIR': str(baseline.cache / 'numba'),
        'PYTHONPYCACHEPREFIX': str(baseline.cache / 'pyc'),
    }


def probed(command):
    """Return the command that runs `python -m valve_sim.ros.valve_node_main` via PHASE_PROBE."""
    return [command[0], '-X', 'importtime', '-c', PHASE_PROBE]


def start_up(probe, kind, index, command, changes, cache=None, keep_log=False):
    """
    Start one node; return its seconds to the first message, ready seconds and CPU seconds.

    ready: from its log line (None for the bare node); CPU: user + system time it had
    used by then, which the load of other work stretches less than the wall time.
    keep_log: also return the log and the start and arrival times (for phases).
    """
    namespace = f'/{kind}{index}'
    subscription = probe.watch(namespace)
    env = {key: value for key, value in os.environ.items() if key != 'NUMBA_CACHE_DIR'}
    for name in ('PYTHONPYCACHEPREFIX', 'PYTHONDONTWRITEBYTECODE'):  # byte code as installed
        env.pop(name, None)
    env.update(changes, PYTHONUNBUFFERED='1')
    if cache is not None:
        env['NUMBA_CACHE_DIR'] = str(cache)
    command = command + ['--ros-args', '-r', f'__ns:={namespace}']
    with tempfile.TemporaryFile('w+') as log:
        started = time.monotonic()
        process = subprocess.Popen(
            command, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=tempfile.gettempdir()
        )
        try:
            while namespace not in probe.arrived:
                if process.poll() is not None or time.monotonic() - started > TIMEOUT:
                    log.seek(0)
                    raise RuntimeError(f'{kind} node gave no state: {log.read()[-2000:]}')
                time.sleep(0.005)
            cpu = cpu_seconds(process.pid)
        finally:
            process.terminate()
            process.wait(timeout=60)
        log.seek(0)
        text = log.read()
        ready = READY.search(text)
    probe.node.destroy_subscription(subscription)
    arrived = probe.arrived[namespace]
    figures = (arrived - started, float(ready[1]) if ready else None, cpu)
    return figures + (text, started, arrived) if keep_log else figures


def cpu_seconds(pid):
    """Return the user + system CPU seconds of a running process (/proc/PID/stat)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def summary(values):
    return {
        'runs': len(values),
        'median_s': statistics.median(values),
        'min_s': min(values),
        'max_s': max(values),
    }


LABELS = {
    'bare': 'bare rclpy node',
    'built': 'valve_node, first start after colcon build',
    'symlinked': 'valve_node, first start, --symlink-install',
    'warm': 'valve_node, kernels cached',
    'cold': 'valve_node, empty kernel cache',
    'baseline': 'valve_node of --baseline, kernels cached',
}


class Baseline:
    """Another checkout to start beside this one: its tree and its caches' folder."""

    def __init__(self, tree, folder):
        self.tree, self.cache = tree.resolve(), folder / 'baseline'


def measure(args, folder):
    """Build, then start the nodes as planned; return {kind: [(seconds, ready, cpu)]}."""
    precompile = [sys.executable, '-m', 'valve_sim.core.precompile']
    subprocess.run(precompile, check=True, env=dict(os.environ), timeout=BUILD_TIMEOUT)
    baseline = Baseline(args.baseline, folder) if args.baseline else None
    if baseline:
        subprocess.run(
            precompile, check=True, env={**os.environ, **baseline_env(baseline)},
            timeout=BUILD_TIMEOUT, cwd=tempfile.gettempdir(),
        )
    prefix, build_seconds = {}, {}
    prefix['built'], build_seconds['built'] = colcon_build(folder)
    prefix['symlinked'], build_seconds['symlinked'] = colcon_build(
        folder / 'symlinked', '--symlink-install', cache=folder / 'symlinked_cache'
    )
    for kind, seconds in build_seconds.items():
        print(f"colcon build, {kind}: {seconds:.1f} s, the kernels' compile included", flush=True)
    probe = FirstMessage()
    start_up(probe, 'bare', 'warmup', *node_command('bare', prefix))  # warms DDS and the probe
    rotation = ('bare', 'warm') + (('baseline',) if baseline else ())
    for kind in rotation[1:]:  # fill their byte-code caches, as an installed package has
        start_up(probe, kind, 'warmup', *node_command(kind, prefix, baseline))
    plan = (
        [('built', 0), ('symlinked', 0)]
        + [(kind, i) for i in range(args.warm) for kind in rotation]
        + [('cold', i) for i in range(args.cold)]
    )
    runs = {kind: [] for kind in LABELS}
    for kind, i in plan:
        command, changes = node_command(kind, prefix, baseline)
        cache = {'cold': folder / f'cold{i}', 'symlinked': folder / 'symlinked_cache'}.get(kind)
        seconds, ready, cpu = start_up(probe, kind, i, command, changes, cache)
        runs[kind].append((seconds, ready, cpu))
        print(
            f'{kind:<5} run {i + 1}: first state after {seconds:6.2f} s, {cpu:5.2f} s of CPU'
            + (f' (steady state + kernels {ready:.2f} s)' if ready else ''),
            flush=True,
        )
    spent = {kind: [] for kind in rotation[1:]}
    for i in range(args.phases):
        for kind in spent:
            command, changes = node_command(kind, prefix, baseline)
            seconds, ready, _, log, started, arrived = start_up(
                probe, f'{kind}phases', i, probed(command), changes, keep_log=True
            )
            spent[kind].append(phases(log, started, arrived, ready))
            print(f'{kind} phases run {i + 1}: first state after {seconds:6.2f} s', flush=True)
    return runs, build_seconds, spent


def phase_table(spent):
    """Print the median seconds of each phase per kind; return them as {kind: {phase: s}}."""
    medians = {
        kind: {phase: statistics.median(run[phase] for run in runs) for phase in runs[0]}
        for kind, runs in spent.items() if runs
    }
    if not medians:
        return medians
    kinds = list(medians)
    print()
    print(f'{"where a warm start goes (median s)":<36}' + ''.join(f'{k:>10}' for k in kinds))
    for phase in medians[kinds[0]]:
        print(f'{phase:<36}' + ''.join(f'{medians[k][phase]:10.3f}' for k in kinds))
    totals = [sum(s for phase, s in medians[k].items() if phase != LATER_IMPORTS) for k in kinds]
    print(f'{"total":<36}' + ''.join(f'{total:10.3f}' for total in totals))
    return medians


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--warm', type=int, default=5, help='warm runs (and bare runs)')
    parser.add_argument('--cold', type=int, default=1, help='cold runs (empty kernel cache)')
    parser.add_argument('--json', type=Path, help='also write the figures as JSON')
    parser.add_argument(
        '--baseline', type=Path,
        help="another checkout (e.g. main's) whose valve_node joins the warm rotation",
    )
    parser.add_argument(
        '--phases', type=int, default=0,
        help='probed warm starts (and baseline ones) that say where the time goes',
    )
    args = parser.parse_args()
    claim_domain(keep_existing=False)
    os.environ['PYTHONPATH'] = os.pathsep.join(
        filter(None, [str(REPO), os.environ.get('PYTHONPATH')])
    )
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix='bench_startup_') as folder:
        runs, build_seconds, spent = measure(args, Path(folder))
    figures = {
        'load_average_start': load_start,
        'load_average_end': os.getloadavg(),
        'colcon_build_s': build_seconds['built'],
        'colcon_build_symlink_install_s': build_seconds['symlinked'],
        **{kind: summary([s for s, _, _ in values]) for kind, values in runs.items() if values},
        **{
            f'{kind}_kernels': summary([r for _, r, _ in values if r is not None])
            for kind, values in runs.items()
            if any(r is not None for _, r, _ in values)
        },
        **{f'{kind}_cpu': summary([c for _, _, c in values]) for kind, values in runs.items()
           if values},
    }
    bare = figures['bare']['median_s']
    figures['targets'] = {
        kind: {
            'above_bare_s': figures[kind]['median_s'] - bare,
            'target_above_bare_s': limit,
            'met': figures[kind]['median_s'] - bare <= limit,
        }
        for kind, limit in TARGETS.items()
    }
    print()
    print(f'{"start-up to first state":<44}{"median":>9}{"min":>9}{"max":>9}{"- bare":>9}')
    for kind in LABELS:
        rows = (
            (kind, LABELS[kind]),
            (f'{kind}_kernels', '  of which steady state + kernels'),
            (f'{kind}_cpu', '  CPU time used by then'),
        )
        for key, label in rows:
            if key in figures:
                f = figures[key]
                above = f'{f["median_s"] - bare:+8.2f}s' if key == kind != 'bare' else ''
                print(
                    f'{label:<44}{f["median_s"]:8.2f}s{f["min_s"]:8.2f}s{f["max_s"]:8.2f}s{above}'
                )
    for kind, target in figures['targets'].items():
        print(
            f'target {LABELS[kind]} <= bare + {target["target_above_bare_s"]:g} s: '
            f'{target["above_bare_s"]:+.2f} s, {"met" if target["met"] else "NOT met"}'
        )
    figures['phases'] = phase_table(spent)
    print(
        f'load average {load_start[0]:.2f} at start, {figures["load_average_end"][0]:.2f} at end'
    )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
