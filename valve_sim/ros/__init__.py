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
ROS 2 adapters: valve_node, analyser_node and their helpers.

Lives here: the nodes, parameter descriptors from specs, diagnostics, spinning, and
valve_node's fault and sensor parameters (fault_injection) and its ticks of a /clock
jump (clock_jumps); node processes, lockstep and scenario runs; a replay publisher of
simulated ticks (replay), and the demo's own node and run (demo_driver); valve_node as
a managed node (managed_valve_node) and as a simulator stepped through
simulation_interfaces (simulation_server, scenario_stepper).
The home of rclpy (the only wing that uses it, with the testing kit); nodes stay thin
around valve_sim.core and valve_sim.analysis.
May import: valve_sim.core, valve_sim.analysis, valve_sim.recording, rclpy.

A node process (`python -m valve_sim.ros.<module>`, or its console script) ends
quietly on SIGINT or SIGTERM while it is still starting up (exit code 128 + the
signal's number): this package is imported before the node's own (slow) imports,
and spinning.init() later installs the handlers that stop the node cleanly.
Without this, Python's KeyboardInterrupt traceback. The handlers are installed
before anything else runs here; what runs before this package (the interpreter's
own start-up) is CPython's, which ends on SIGINT with a message of its own.
"""

# The builtin _signal: importing `signal` would first run its enum set-up, during
# which a Ctrl-C would still give a traceback.
import _signal
import os
import sys


PARENT_VARIABLE = 'VALVE_SIM_PARENT_PID'  # set by ros.node_processes for its node processes
PR_SET_PDEATHSIG = 1  # linux/prctl.h
NODE_PROGRAMS = {'valve_node': 'valve_node_main', 'analyser_node': 'analyser_node',  # module
                 'managed_valve_node': 'managed_valve_node',
                 'valve_simulator': 'simulation_server'}


def _exit_quietly(number, _frame):
    """
    End the process at once, as a shell expects after a signal (exit code 128 + number).

    Not by an exception: raised inside an extension module's import it would come
    out as that module's ImportError, with a traceback. Nothing is open yet.
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):
            pass
    os._exit(128 + number)


# sys.argv[0] is '-m' while `python -m` imports the packages of the module it runs.
if sys.argv[:1] == ['-m'] or sys.argv and os.path.basename(sys.argv[0]) in NODE_PROGRAMS:
    try:
        _signal.signal(_signal.SIGINT, _exit_quietly)
        _signal.signal(_signal.SIGTERM, _exit_quietly)
    except ValueError:  # not the main thread: an embedding program's own handlers
        pass
    _parent = os.environ.pop(PARENT_VARIABLE, '')  # popped: this node's children lack it
    if _parent.isdigit() and sys.platform.startswith('linux'):
        import ctypes  # SIGTERM when the run's process ends, even killed: a clean stop
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, _signal.SIGTERM)
        if os.getppid() != int(_parent):  # it ended before prctl
            _exit_quietly(_signal.SIGTERM, None)


def node_command(program, options=(), parameters=None, ros_args=()):
    """
    Return the command that runs a node program of NODE_PROGRAMS with this Python.

    python -m valve_sim.ros.MODULE OPTIONS [--ros-args -p NAME:=VALUE ... ROS_ARGS], MODULE
    the program's module; parameters: {name: value} set at start.
    """
    ros = [f'{name}:={value}' for name, value in (parameters or {}).items()]
    ros = [item for assignment in ros for item in ('-p', assignment)] + list(ros_args)
    return [sys.executable, '-m', f'valve_sim.ros.{NODE_PROGRAMS[program]}', *options] + (
        ['--ros-args', *ros] if ros else []
    )
