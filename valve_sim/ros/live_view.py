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
A live view without a ROS install: topics served over the Foxglove WebSocket protocol.

The Foxglove app (or any client of the protocol) connects to ws://HOST:PORT and sees
each topic as a channel with its ROS 2 schema (encoding ros2msg: the full message
definition, as in a bag) and CDR messages, the same bytes the node publishes over
DDS. foxglove-sdk (PyPI) runs the server in its own threads. A message is handed
to it only while a client subscribes to its channel, so the node's tick pays one
attribute check when nobody watches. On a ROS install, foxglove_bridge serves
every topic of the graph instead, and needs nothing from valve_sim.
"""

from pathlib import Path

from valve_sim.core.errors import InputFileError
from valve_sim.core.extras import require


DEFAULT_PORT = 8765  # Foxglove's default WebSocket port
DEFAULT_HOST = '127.0.0.1'  # this machine only; 0.0.0.0 serves the network
LAYOUT = 'valve_layout.json'  # the valve's Foxglove layout, installed in share/valve_sim/foxglove


def layout_path():
    """
    Return the path of the valve's Foxglove layout, where this installation has it.

    A colcon or pip install has it in its prefix's share/valve_sim/foxglove, a clone or
    an editable install in the source tree (valve_sim.core.parameters.shipped_file);
    the source tree's path, if none has it.
    """
    from valve_sim.core.errors import ParameterError
    from valve_sim.core.parameters import shipped_file

    try:
        return shipped_file('foxglove', LAYOUT)
    except ParameterError:
        return Path(__file__).resolve().parents[2] / 'foxglove' / LAYOUT


def port_number(text):
    """Parse a TCP port, 0 (any free port) to 65535 (argparse type)."""
    from argparse import ArgumentTypeError

    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= MAX_PORT:
        raise ArgumentTypeError(f'a port must be in [0, {MAX_PORT}], got {text!r}')
    return port


MAX_PORT = 65535
port_number.bounds = f'in [0, {MAX_PORT}]'


def add_port_option(parser, help_text):
    """Add --foxglove [PORT] (DEFAULT_PORT when given without a number) to an argparse parser."""
    parser.add_argument(
        '--foxglove', nargs='?', const=DEFAULT_PORT, type=port_number, metavar='PORT',
        help=f'{help_text} (a port {port_number.bounds})'
    )


class LiveView:
    """A Foxglove WebSocket server for given topics; log() hands it serialized messages."""

    def __init__(self, topics, port=DEFAULT_PORT, host=DEFAULT_HOST, name='valve_sim'):
        """
        Start serving topics {resolved topic name: 'pkg/msg/Type'} on host:port.

        Port 0 takes a free port (see self.port). Raises InputFileError if
        foxglove-sdk is missing or the port cannot be opened.
        """
        from valve_sim.recording.bag import message_definition  # a node without a view: no MCAP

        require('the Foxglove live view (on a ROS install: foxglove_bridge)', 'foxglove',
                'foxglove', error=InputFileError)
        import foxglove
        self._subscriptions = set()  # (client id, channel id) of every client subscription
        self._context = foxglove.Context()
        self.channels = {
            topic: foxglove.Channel(
                topic,
                message_encoding='cdr',
                schema=foxglove.Schema(
                    name=type_name,
                    encoding='ros2msg',
                    data=message_definition(type_name).encode(),
                ),
                context=self._context,
            )
            for topic, type_name in topics.items()
        }
        try:
            self.server = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                server_listener=_Subscriptions(self._subscriptions),
                context=self._context,
            )
        except RuntimeError as error:
            raise InputFileError(f'Foxglove live view on {host}:{port}: {error}') from error
        self.host, self.port = host, self.server.port

    @property
    def watched(self):
        """Whether any client subscribes to any channel."""
        return bool(self._subscriptions)

    def log(self, topic, data, time_ns):
        """Hand one serialized (CDR) message of topic, stamped time_ns [ns], to its subscribers."""
        channel = self.channels[topic]
        if channel.has_sinks():
            channel.log(data, log_time=time_ns)

    def close(self):
        self.server.stop()


class _Subscriptions:
    """foxglove.websocket.ServerListener: keeps the set of client subscriptions up to date."""

    def __init__(self, subscriptions):
        self._subscriptions = subscriptions

    def on_subscribe(self, client, channel):
        self._subscriptions.add((client.id, channel.id))

    def on_unsubscribe(self, client, channel):  # also on a disconnect
        self._subscriptions.discard((client.id, channel.id))
