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

"""The middleware's receive threads put behind the tick, in this process's own threads."""

import os
from pathlib import Path
import sys
import threading

import pytest
from valve_sim.ros.receive_threads import ReceiveThreads


pytestmark = pytest.mark.skipif(sys.platform != 'linux', reason='thread policies of Linux')


class NamedThread:
    """A thread of this process that waits, under an OS-level name (its comm)."""

    def __init__(self, name):
        self.release = threading.Event()
        started = threading.Event()
        self.thread = threading.Thread(target=lambda: (started.set(), self.release.wait(60)))
        self.thread.start()
        started.wait(60)
        self.tid = self.thread.native_id
        Path(f'/proc/self/task/{self.tid}/comm').write_text(name)

    def stop(self):
        self.release.set()
        self.thread.join(60)


@pytest.fixture
def threads():
    started = {}

    def start(name):
        started[name] = NamedThread(name)
        return started[name].tid

    yield start
    for thread in started.values():
        thread.stop()


def test_only_the_receive_threads_go_idle_and_only_once(threads):
    receive = threads('dds.shm.7411')
    other = threads('dds.ev.0')
    receive_threads = ReceiveThreads('idle')
    assert 'dds.shm.7411' in receive_threads.update()
    assert os.sched_getscheduler(receive) == os.SCHED_IDLE
    assert os.sched_getscheduler(other) == os.SCHED_OTHER
    assert os.sched_getscheduler(threading.main_thread().native_id) == os.SCHED_OTHER
    assert receive_threads.update() == []  # nothing new
    later = threads('dds.udp.7412')  # a receive thread started after the first look
    assert receive_threads.update() == ['dds.udp.7412']
    assert os.sched_getscheduler(later) == os.SCHED_IDLE
    description = receive_threads.describe()
    assert description.startswith('SCHED_IDLE: ') and 'dds.udp.7412' in description
    assert 'dds.ev.0' not in description


def test_normal_leaves_every_thread_as_it_is(threads):
    receive = threads('dds.shm.7413')
    receive_threads = ReceiveThreads('normal')
    assert receive_threads.update() == []
    assert os.sched_getscheduler(receive) == os.SCHED_OTHER
    assert receive_threads.describe().startswith('normal')


def test_a_process_without_receive_threads_says_so(tmp_path):
    (tmp_path / '123').mkdir()
    (tmp_path / '123' / 'comm').write_text('python\n')
    receive_threads = ReceiveThreads('idle', tasks=tmp_path)
    assert receive_threads.update() == []
    assert 'none found' in receive_threads.describe()


def test_a_receive_thread_under_a_real_time_policy_keeps_it(threads):
    receive = threads('dds.shm.7414')
    try:
        os.sched_setscheduler(receive, os.SCHED_FIFO, os.sched_param(1))
    except PermissionError:
        pytest.skip('SCHED_FIFO needs CAP_SYS_NICE')
    receive_threads = ReceiveThreads('idle')
    assert receive_threads.update() == []
    assert os.sched_getscheduler(receive) == os.SCHED_FIFO
    assert 'real-time policy kept' in receive_threads.describe()
