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
How valve_sim's node processes run: one node on an executor until SIGINT or SIGTERM.

The signals only set a flag that ends the spin loop; rclpy's own handlers are
off. So a node finishes its work (the analyser closes its file) with the
middleware still up, and no exception is raised inside a callback or under a
running executor (rclpy's EventsExecutor.spin() does not return on a signal,
but its spin_once() does).
"""

import signal
import threading

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions


try:
    from rclpy.experimental import EventsExecutor
except ImportError:  # rclpy releases before the EventsExecutor (early Jazzy)
    EventsExecutor = None

EXECUTORS = {'single-threaded': SingleThreadedExecutor}
if EventsExecutor is not None:
    EXECUTORS = {'events': EventsExecutor, **EXECUTORS}
DEFAULT_EXECUTOR = next(iter(EXECUTORS))  # events where there is one
SPIN_TIMEOUT = 0.1  # [s] the longest a signal waits for the spin loop to notice it


def init(args=None):
    """
    Call rclpy.init with valve_sim's signal handling.

    Returns the Event that SIGINT and SIGTERM set.
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    return stop


def spin_until(node, executor, stop):
    """
    Spin node on executor until the Event stop is set.

    The executor then lets go of it, as rclpy.spin() does.
    """
    executor.add_node(node)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=SPIN_TIMEOUT)
    finally:
        executor.remove_node(node)
        executor.shutdown()
