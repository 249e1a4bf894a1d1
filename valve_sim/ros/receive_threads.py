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
The middleware's receive threads in a node's process, and keeping them behind the tick.

Under a flood of messages the middleware's receive threads (C++, outside Python's
GIL) take CPU in the node's own process, and under the normal policy a waking tick
can wait for a receive thread's time slice. Under SCHED_IDLE (sched(7)) a receive
thread still runs whenever no ordinary thread wants the CPU, and a waking ordinary
thread (the tick) preempts it at once. Any process may put its own threads there,
no privilege needed; going back to the normal policy needs CAP_SYS_NICE (or
RLIMIT_NICE 20), so it is done once, for the process's life. Threads that already
run under a real-time policy (the node started with chrt) keep it: whoever chose
it set the priorities.

The receive threads are found by their names in /proc/self/task: Fast DDS (2.14 and
later, Jazzy's default middleware) names them dds.<transport>.<port>. With another
middleware none match, and the threads stay as they are.
"""

import os
from pathlib import Path
import re


RECEIVE_THREAD = re.compile(r'dds\.(udp|udp6|shm|tcp|tcp6)\.\d+$')  # Fast DDS: transport.port
POLICIES = {'idle': 'SCHED_IDLE', 'normal': None}  # --receive-threads: os's policy names
# normal by default: on a machine busy with other work an idle receive thread waits long
# for the CPU and delays the tick more than it spares it (docs/valve_node.md)
DEFAULT_POLICY = 'normal'
TASKS = Path('/proc/self/task')


class ReceiveThreads:
    """
    The middleware's receive threads of this process under policy (a POLICIES key).

    update() finds threads started since it last looked and sets their policy;
    describe() says what was done, for diagnostics and the start-up log.
    """

    def __init__(self, policy, tasks=TASKS):
        self.policy = policy
        self.tasks = tasks
        self.names = []  # the receive threads found, in the order found
        self.error = ''  # why a thread's policy could not be set
        self.real_time = 0  # receive threads left under a real-time policy (SCHED_FIFO, RR)
        self._seen = set()  # thread ids looked at

    def update(self):
        """Set the policy of receive threads started since the last call; return their names."""
        if POLICIES[self.policy] is None:  # left as the middleware starts them
            return []
        try:
            tids = os.listdir(self.tasks)
        except OSError as error:  # no /proc (not Linux)
            self.error = self.error or f'cannot list threads: {error}'
            return []
        found = []
        for tid in set(tids) - self._seen:  # names are read once, when a thread is new
            self._seen.add(tid)
            name = _thread_name(self.tasks / tid)
            if name is not None and RECEIVE_THREAD.match(name) and self._set_policy(int(tid)):
                found.append(name)
        self.names += found
        return found

    def _set_policy(self, tid):
        name = POLICIES[self.policy]
        try:
            if os.sched_getscheduler(tid) not in (os.SCHED_OTHER, os.SCHED_BATCH):
                self.real_time += 1  # under chrt: its priority was chosen, keep it
                return False
            os.sched_setscheduler(tid, getattr(os, name), os.sched_param(0))
        except ProcessLookupError:  # ended meanwhile
            return False
        except (AttributeError, OSError) as error:  # not Linux, or a sandbox that forbids it
            self.error = self.error or f'cannot set {name}: {error}'
            return False
        return True

    def describe(self):
        """Return e.g. 'SCHED_IDLE: dds.shm.7411, dds.udp.7411' (or why not) for diagnostics."""
        if POLICIES[self.policy] is None:
            return 'normal (left as started)'
        if self.real_time and not self.names:
            return f'real-time policy kept ({self.real_time} threads, e.g. from chrt)'
        names = ', '.join(self.names) or 'none found (not Fast DDS?)'
        return f'{POLICIES[self.policy]}: {names}' + (f'; {self.error}' if self.error else '')


def _thread_name(task):
    try:
        return (task / 'comm').read_text().strip()
    except OSError:  # ended meanwhile
        return None
