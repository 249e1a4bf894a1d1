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
valve_node's process: its command line and main(), the console script `valve_node`.

main() parses the node's own options (--executor, --receive-threads, --foxglove,
--foxglove-host; ROS arguments removed), starts ReliefValveNode (valve_sim.ros.valve_node)
and spins it until SIGINT or SIGTERM. A start-up error (STARTUP_ERRORS) is logged as
fatal and ends the process with exit code 1. Run it as `valve_node` or
`python -m valve_sim.ros.valve_node_main` (valve_sim.ros.node_command).

Automatic garbage collection is off from the import of the node's module (numba, numpy)
on: the start makes about 200,000 objects and little garbage (about a thousand), and
collections during it only cost CPU (docs/benchmarks.md, start-up). The start-up objects
are frozen before the node spins; its housekeeping collects the young generations.
"""

import argparse
import gc
import sys

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.utilities import remove_ros_args
from valve_sim.core.errors import InputFileError, ParameterError, SteadyStateError
from valve_sim.core.input_documents import MAX_ALIASES, MAX_DEPTH
from valve_sim.core.input_files import FAULT_SCHEDULE as FAULT_SCHEDULE_FILE, MAX_EVENTS
from valve_sim.core.parameters import NODE_NAME
from valve_sim.ros import live_view, spinning
from valve_sim.ros.receive_threads import DEFAULT_POLICY, POLICIES


STARTUP_ERRORS = (ParameterError, SteadyStateError, ParameterException, InputFileError)


def parse_arguments(args):
    """valve_node's own command line (ROS arguments removed)."""
    parser = argparse.ArgumentParser(
        prog='valve_node',
        description='The virtual relief valve as a ROS 2 node.',
        epilog=(
            f'fault_schedule: a regular file of {FAULT_SCHEDULE_FILE.limits()} and at most '
            f'{MAX_EVENTS:,} events (YAML, UTF-8, at most {MAX_ALIASES} aliases, '
            f'{MAX_DEPTH} levels deep), read in a process of its own when set live; a '
            '/clock before 0 s or at or past 2^31 s is ignored and counted. '
            'docs/valve_node.md, "Files it reads, and other hostile input".'
        ),
    )
    parser.add_argument(
        '--executor',
        choices=spinning.EXECUTORS,
        default=spinning.DEFAULT_EXECUTOR,
        help=(
            f'rclpy executor that runs the node (default {spinning.DEFAULT_EXECUTOR}; '
            "events, rclpy's EventsExecutor, "
            "costs a third of single-threaded's CPU time per tick: docs/valve_node.md)"
        ),
    )
    parser.add_argument(
        '--receive-threads',
        choices=POLICIES,
        default=DEFAULT_POLICY,
        help=(
            f"scheduling of the middleware's receive threads (default {DEFAULT_POLICY}: as "
            'the middleware starts them; idle: SCHED_IDLE, so that a flood of messages '
            'cannot delay the tick on a machine that does nothing else; docs/valve_node.md)'
        ),
    )
    live_view.add_port_option(
        parser,
        'serve the tick topics and /diagnostics over the Foxglove WebSocket protocol '
        f'(default port {live_view.DEFAULT_PORT}; 0: any free port); the layout to open: '
        f'{live_view.layout_path()}. On a ROS install, run foxglove_bridge instead',
    )
    parser.add_argument(
        '--foxglove-host',
        default=live_view.DEFAULT_HOST,
        metavar='HOST',
        help='address the Foxglove server listens on '
        f'(default {live_view.DEFAULT_HOST}, this machine; '
        '0.0.0.0 for the network)',
    )
    return parser.parse_args(remove_ros_args(sys.argv if args is None else args)[1:])


def main(args=None):
    """Run valve_node until SIGINT or SIGTERM; returns the exit code."""
    options = parse_arguments(args)
    gc.disable()  # the node collects in its housekeeping, between ticks
    from valve_sim.ros.valve_node import ReliefValveNode  # here: imported without collections

    stop = spinning.init(args)
    try:
        node = ReliefValveNode(sys.argv if args is None else args)
    except STARTUP_ERRORS as error:
        rclpy.logging.get_logger(NODE_NAME).fatal(f'cannot start: {error}')
        rclpy.try_shutdown()
        return 1
    try:
        if options.foxglove is not None:
            node.serve_live_view(options.foxglove, options.foxglove_host)
        node.get_logger().info(f'executor: {options.executor}')
        node.use_receive_thread_policy(options.receive_threads)
        gc.freeze()  # start-up objects stay out of the housekeeping's scans
        spinning.spin_until(node, spinning.EXECUTORS[options.executor](), stop)
    except InputFileError as error:  # the live view's port or foxglove-sdk
        node.get_logger().fatal(f'cannot start: {error}')
        return 1
    finally:
        if node.live_view is not None:
            node.live_view.close()
        node.schedule_loader.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
