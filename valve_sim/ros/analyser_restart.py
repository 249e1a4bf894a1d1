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
analyser_node's restart: a new recording in the running process (~/restart).

A suite of scenarios (ros.scenario_suite) records each scenario into a bag of its own
on one analyser_node. The service ~/restart (rcl_interfaces/srv/SetParametersAtomically,
as valve_node's, valve_sim.ros.valve_restart) starts recording anew as if the node had
been launched with the request's parameters too (over its start-up values, not over
an earlier restart's): the current recording is closed as at shutdown (what is queued
taken and written, the open steps measured and published, the file closed with its
summary, or metadata.yaml for a bag folder); a new recording opens (a new file in
output_dir, its own .measures.json, valve_node's start parameters read again:
ros.start_parameters) and the node's clock goes back to zero through its guard, so the
next /clock starts a new time base as a first one does. A topic recorded before keeps
its subscription if the new recording records it with the same type and QoS (its
publishers stay matched: nothing sent after the restart is missed while a new one
would match); a transient-local topic's subscription is made anew, so its publishers'
history comes again, as to a new node (recorder.Recorder.handed_over). The node's parameters then
read as the new recording's. The new file is created before anything else changes: a
refused request (an unknown parameter, a wrong value, a folder that cannot be made, a
parameter only a new process can change: use_sim_time, hardware_id) leaves the current
recording as it was. step_measures keeps one publisher (its transient-local history
spans recordings; each message names its bag). A request repeated within
REPEAT_WINDOW of the same successful one is answered as that one was, without a new
recording: a client that missed the answer asks again, and must not get a second bag.
"""

import time

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from valve_sim.core.catalogue import ANALYSER_DOUBLES
from valve_sim.core.errors import OutputFileError, ParameterError
from valve_sim.ros.ros_parameters import value_problem


SERVICE = '~/restart'
# [s] a request the same as the last restart's, this soon after it, is its client asking
# again for an answer Fast DDS dropped (lockstep_protocol.answer): answered, not redone
REPEAT_WINDOW = 10.0
DOUBLES = {spec.name: spec for spec in ANALYSER_DOUBLES}


def checked_value(name, value, start):
    """
    Return value as the parameter name takes it (start: its start-up value).

    Raises ParameterError naming the parameter and what it takes.
    """
    if name in DOUBLES:
        problem = value_problem(DOUBLES[name], Parameter(name, value=value))
        if problem:
            raise ParameterError(problem)
        return float(value)
    if isinstance(start, list):
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise ParameterError(f"parameter '{name}' takes a list of strings, got {value!r}")
        return list(value)
    if type(value) is not type(start):  # noqa: E721 (a bool is no integer here)
        raise ParameterError(f"parameter '{name}' takes a {type(start).__name__}, "
                             f'got {value!r}')
    return value


def settings_with(node, overrides):
    """
    Return the node's start-up settings with overrides {name: value} over them.

    Raises ParameterError for a name the node lacks, a wrong value, or a parameter that
    only a new process can change (any but the node's own settings).
    """
    settings = dict(node.start_settings)
    for name, value in overrides.items():
        if name in settings:
            settings[name] = checked_value(name, value, node.start_settings[name])
        elif not node.has_parameter(name):
            raise ParameterError(f'analyser_node has no parameter {name!r}')
        elif node.get_parameter(name).value != value:
            raise ParameterError(f'parameter {name!r} cannot change in a restart: it keeps '
                                 f'{node.get_parameter(name).value!r}; start a new '
                                 f'analyser_node for {value!r}')
    low, high = 10, 1_000_000  # the queue_depth descriptor's range
    if not low <= settings['queue_depth'] <= high:
        raise ParameterError(f"parameter 'queue_depth' must be in [{low}, {high}] messages, "
                             f"got {settings['queue_depth']}")
    return settings


def restart(node, overrides):
    """
    Restart a ValveAnalyser's recording with overrides; returns the result's reason.

    Raises ParameterError or OutputFileError, the node unchanged.
    """
    settings = settings_with(node, overrides)
    recording = node.new_recording(settings)  # its file created: the last step that can fail
    closed = node.bag.path
    problem = node.restart(settings, recording)
    for name, value in settings.items():  # read-only: rclpy has no public way to set them
        node._parameters[name] = Parameter(name, value=value)
    return (f'closed {closed}' + (f' ({problem})' if problem else '')
            + f'; recording to {node.bag.path}')


def serve(node):
    """Create a ValveAnalyser's ~/restart service (rcl_interfaces/srv/SetParametersAtomically)."""
    from rcl_interfaces.srv import SetParametersAtomically

    last = {}  # the last restart done: its overrides, when, its reason

    def on_restart(request, response):
        overrides = {p.name: Parameter.from_parameter_msg(p).value for p in request.parameters}
        if (last.get('overrides') == overrides
                and time.monotonic() - last['at'] < REPEAT_WINDOW):
            response.result = SetParametersResult(successful=True, reason=last['reason'])
            return response  # the same request again: its answer was lost, not the restart
        try:
            reason = restart(node, overrides)
        except (ParameterError, OutputFileError) as error:
            response.result = SetParametersResult(
                successful=False, reason=f'restart refused, nothing changed: {error}')
            node.get_logger().warn(response.result.reason)
            return response
        response.result = SetParametersResult(successful=True, reason=reason)
        last.update(overrides=overrides, at=time.monotonic(), reason=reason)
        node.get_logger().info(reason)
        return response

    return node.create_service(SetParametersAtomically, SERVICE, on_restart)
