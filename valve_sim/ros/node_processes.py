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
valve_node and analyser_node as the processes of a run: started, watched, stopped with SIGINT.

`valve-sim demo`, the scenario runner and the test kit start the nodes this way: each
a process of this Python (valve_sim.ros.node_command) in the run's ROS domain (the
environment's ROS_DOMAIN_ID, which valve_sim.ros.isolation.claim_domain sets), its
output in FOLDER/<name>.log. spin_until() spins a driving node until a condition
holds, and says which node died (and where its log is) if one ends meanwhile.
"""

import os
import signal
import subprocess
import time

from valve_sim.core.errors import NodeExitError, WaitTimeoutError
from valve_sim.core.output_files import fresh_file
from valve_sim.ros import node_command, PARENT_VARIABLE
from valve_sim.ros.isolation import held_lock_fds


STOP_TIMEOUT = 20.0  # [s] for each node to finish after SIGINT
# exit codes of a node that the SIGINT ended before it was up (valve_sim.ros's start-up
# handler: 128 + SIGINT; earlier still, Python's own KeyboardInterrupt: killed by SIGINT)
STARTING_CODES = (128 + signal.SIGINT, -signal.SIGINT)


class NodeProcesses:
    """Node processes by name, logs in a folder."""

    def __init__(self, folder, commands, env=None):
        """Start each of commands {name: argv} with its output in folder/<name>.log."""
        self.folder, self.processes = folder, {}
        # each node dies with this process (valve_sim.ros: PR_SET_PDEATHSIG) and holds its
        # domain's lock meanwhile: a node left behind never answers another run's /clock
        env = {**(os.environ if env is None else env), PARENT_VARIABLE: str(os.getpid())}
        for name, command in commands.items():
            with fresh_file(folder / f'{name}.log') as log:  # a link there not followed
                self.processes[name] = subprocess.Popen(
                    command, stdout=log, stderr=subprocess.STDOUT, env=env,
                    pass_fds=held_lock_fds()
                )

    def log(self, name):
        return self.folder / f'{name}.log'

    def check(self, what):
        """Raise NodeExitError (a ChildProcessError) if a node ended (while waiting for what)."""
        for name, process in self.processes.items():
            if process.poll() is not None:
                raise NodeExitError(
                    f'{name} ended with code {process.returncode} while waiting for '
                    f'{what} (log: {self.log(name)})'
                )

    def stop(self):
        """SIGINT each running node and wait; NodeExitError if one does not end cleanly."""
        for process in self.processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        failures = []
        for name, process in self.processes.items():
            try:
                code = process.wait(STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
                failures.append(
                    f'{name} did not stop within {STOP_TIMEOUT:g} s of SIGINT and was killed'
                )
                continue
            if code in STARTING_CODES:
                failures.append(
                    f'{name} was still starting when stopped (exit code {code}): it took no '
                    'part in the run; if the run got that far, other nodes in ROS domain '
                    f"{os.environ.get('ROS_DOMAIN_ID', '0')} answered in its place")
            elif code != 0:
                failures.append(f'{name} exited with code {code}')
        if failures:
            raise NodeExitError('; '.join(failures) + f' (logs in {self.folder})')


def start_valve_and_analyser(folder, valve_options=(), valve_parameters=None,
                             valve_ros_args=(), analyser_parameters=None, env=None):
    """
    Start valve_node and analyser_node (recording into folder); returns NodeProcesses.

    valve_options: valve_node's own options; *_parameters: {name: value} set at start;
    valve_ros_args: further ROS arguments of valve_node (e.g. --params-file F).
    """
    return NodeProcesses(folder, {
        'valve_node': node_command('valve_node', valve_options, valve_parameters,
                                   valve_ros_args),
        'analyser_node': node_command(
            'analyser_node', parameters={'output_dir': folder, **(analyser_parameters or {})}
        ),
    }, env)


def spin_until(executor, condition, timeout, what, processes=None, period=0.02):
    """
    Spin executor until condition() holds; raises WaitTimeoutError or NodeExitError.

    processes: the NodeProcesses whose end (a node died) is an error meanwhile.
    """
    deadline = time.monotonic() + timeout
    while not condition():
        executor.spin_once(timeout_sec=period)
        if processes is not None:
            processes.check(what)
        if time.monotonic() > deadline:
            where = f' (logs in {processes.folder})' if processes is not None else ''
            raise WaitTimeoutError(f'no {what} within {timeout:g} s{where}')
