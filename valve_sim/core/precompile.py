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
Compile the numba kernels ahead of the first start, into the cache beside the sources.

    python -m valve_sim.core.precompile

valve_node compiles (or loads from numba's cache) its kernels as it starts:
compiled there, the first start of a fresh install takes tens of seconds. setup.py
runs this module right after a `colcon build` (or `setup.py install`) has installed
the package, and run.py after it has set up .venv, each with the interpreter that
runs the node: numba caches beside the sources it imports (valve_sim/core/
__pycache__, see valve_sim.core.jit), so the installed node finds its kernels there.

compile_kernels() goes through what valve_node does as it starts and ticks, with
the reference parameters: the steady state, the trial integration, a tick's
integration, the relief flows and the sensor stage, and a short offline
simulation (`valve-sim simulate`, the analyser's model runs). numba compiles a
kernel per type signature: these calls pass the types the node and the commands
pass (test_install checks that the installed node then compiles nothing).
"""

import sys
import time


STEP_TIME = 0.01  # [s] the short simulation's step of the inlet flow
END_TIME = 0.02  # [s] and its end


def compile_kernels():
    """Compile (or load) every kernel of valve_node's start and ticks and of simulate()."""
    from valve_sim.core.faults import HEALTHY
    from valve_sim.core.parameters import load_parameters
    from valve_sim.core.realtime_model import NS_PER_S, RealTimeModel
    from valve_sim.core.sensors import SensorStage
    from valve_sim.core.simulation import FlowStep, simulate

    loaded = load_parameters()
    params, settings = loaded.params, loaded.settings
    step_size, flow = settings['step_size'], settings['initial_inlet_flow']
    model = RealTimeModel(params, step_size, flow, HEALTHY, 0.0)
    model.trial(params, step_size, flow)
    model.start(0)
    model.advance_to(NS_PER_S // 1000, flow, NS_PER_S, 0.0)
    SensorStage()
    simulate(params, FlowStep(step_time=STEP_TIME, end_time=END_TIME), record_interval=1e-3)


def cache_folder():
    """Return where numba caches the kernels (None without numba or its cache)."""
    from valve_sim.core.integrator import rk4_steps

    cache = getattr(rk4_steps, '_cache', None)
    return getattr(cache, 'cache_path', None)


def main():
    """Compile the kernels; print where they are cached and how long it took."""
    try:
        import numba  # noqa: F401 (only whether it is there)
    except ImportError:
        print('valve_sim: numba is not installed: the kernels run as plain Python')
        return 0
    started = time.perf_counter()
    compile_kernels()
    print(
        f'valve_sim: numba kernels compiled or loaded in {time.perf_counter() - started:.1f} s, '
        f'cached in {cache_folder()}'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
