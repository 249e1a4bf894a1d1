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
A recorded bag's signals as arrays: the bag-to-signals pipeline of analyse and calibrate.

read_recording(path) walks an MCAP file, or the files of a rosbag2 bag folder in
order (rosbag2_metadata.bag_files), with BagReader; each channel that carries a
mapped role gets a decoder from the first of decoder_factories that has one for its
encoding and schema (the mcap library's DecoderFactory protocol: decoder_for(
message_encoding, schema) -> a function of the message bytes, or None; default
mcap_ros2's CDR decoder), and an analysis.steps.signals.Extractor that takes the roles'
values from the decoded messages. The Joiner puts them on the supply pressure's
time axis; the result is a Recording of arrays, what the step analysis
(analysis.recorded_steps) and calibration take.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
import os
from typing import Any, Optional, Union

import numpy as np
from valve_sim.analysis.steps.input_events import ParameterChanges, SettingChanges
from valve_sim.analysis.steps.signals import (
    Extractor,
    FLUID_PRESSURE,
    Joiner,
    JOINT_STATE,
    ROLE,
    ROLES,
    seconds,
    SignalMap,
)
from valve_sim.core.errors import CalibrationError, InputFileError
from valve_sim.recording.bag import BagReader
from valve_sim.recording.rosbag2_metadata import bag_files


# What a bag must hold: a rig records supply pressure and inlet flow, rarely the main valve
# (then T_s comes from the pressure, valve_sim.analysis.steps.measures).
BAG_REQUIRED = ('supply_pressure', 'inlet_flow')


@dataclass
class Recording:
    """A bag's joined signals: arrays over the rows, and what was wrong with the file (or None)."""

    time: np.ndarray  # [s]
    supply_pressure: np.ndarray  # [Pa] gauge
    main_valve: np.ndarray  # [m], NaN where the bag has none
    pilot_poppet: np.ndarray  # [m], NaN where the bag has none
    inlet_flow: np.ndarray  # [m^3/s], NaN where not required and absent
    problem: Optional[str] = None
    inlet_flow_time: Optional[np.ndarray] = None  # [s] each row's flow sample (None: the row's)
    tank_pressure: Optional[np.ndarray] = None  # [Pa] gauge, NaN where the bag has none
    relief_flow: Optional[np.ndarray] = None  # [m^3/s], NaN where the bag has none
    events: Optional[list] = None  # [(time [s], what)]: valve_node's fault and parameter changes

    def valve_pressure(self) -> np.ndarray:
        """Return the supply pressure above the tank [Pa]: p_s - p_t where p_t is known."""
        if self.tank_pressure is None:
            return self.supply_pressure
        return np.where(
            np.isnan(self.tank_pressure),
            self.supply_pressure,
            self.supply_pressure - self.tank_pressure,
        )


def from_every_signal(recording, topics=None):
    """
    Return (the recording from its first row where every signal it holds has a value, note).

    A recorder subscribes topic by topic (analyser_node as rosbag2), so its first rows
    can lack a signal (the main valve, NaN there): they are dropped, every array of the
    recording cut alike, and note (None when nothing was dropped) says which signal
    began how much later. The supply pressure and the inlet flow always count, the main
    valve only if the recording holds it at all. topics: {role: topic} to name them by
    (a SignalMap's topics). CalibrationError when no row has every signal.
    """
    present = {'supply_pressure': recording.supply_pressure, 'inlet_flow': recording.inlet_flow}
    if np.any(np.isfinite(recording.main_valve)):
        present['main_valve'] = recording.main_valve
    known = np.logical_and.reduce([np.isfinite(values) for values in present.values()])
    first = int(np.argmax(known)) if known.any() else len(known)
    if first == 0:
        return recording, None
    if first == len(known):
        raise CalibrationError('no sample of the recording has every mapped signal')
    late = ', '.join(
        f'{ROLE[role].meaning.split(" [")[0]} ({(topics or {}).get(role, role)})'
        for role, values in present.items()
        if not np.isfinite(values[0])
    )
    note = (
        f'the recording starts at its first sample, but {late} begins '
        f'{recording.time[first] - recording.time[0]:.3f} s later: fitting from there '
        f'(the first {first} samples dropped)'
    )
    rows = len(recording.time)
    cut = {
        field.name: getattr(recording, field.name)[first:]
        for field in fields(recording)
        if isinstance(getattr(recording, field.name), np.ndarray)
        and len(getattr(recording, field.name)) == rows
    }
    return replace(recording, **cut), note


def read_recording(
    path: Union[str, os.PathLike[str]], signal_map: Optional[SignalMap] = None,
    required: Sequence[str] = BAG_REQUIRED, decoder_factories: Optional[Sequence[Any]] = None,
) -> Recording:
    """
    Read a bag (an MCAP file or a rosbag2 bag folder) as a Recording.

    Roles not required are NaN where the bag lacks them. decoder_factories: objects
    with decoder_for(message_encoding, schema), asked in order (default: mcap_ros2's).

    Raises InputFileError if a required signal is missing or unreadable.
    """
    if decoder_factories is None:
        from mcap_ros2.decoder import DecoderFactory

        decoder_factories = (DecoderFactory(),)
    signal_map = signal_map or SignalMap()
    optional = [role.name for role in ROLES if role.name not in required]
    joiner, rows = Joiner(required, optional), []
    wanted = {signal_map.topics[role] for role in (*required, *optional)}
    # valve_node's fault_status beside its supply pressure, and its parameter events: their
    # changes end a step's window (analysis.steps.input_events)
    from valve_sim.recording.valve_topics import PARAMETER_EVENTS_TOPIC  # imports the model

    status_topic = signal_map.valve_namespace() + '/fault_status'
    found, problems, events = set(), [], []
    settings = {status_topic: SettingChanges(),
                PARAMETER_EVENTS_TOPIC: ParameterChanges(signal_map.valve_namespace())}
    for file in bag_files(path):  # a file, or the files of a bag folder in order
        reader, extractors = BagReader(file), {}
        for channel, schema, message in reader.messages(wanted | set(settings)):
            if channel.topic in settings:
                events += setting_event(settings[channel.topic], decoder_for(
                    file, channel, schema, decoder_factories), message.data)
                continue
            if channel.id not in extractors:
                decode = decoder_for(file, channel, schema, decoder_factories)
                roles = signal_map.roles_of(channel.topic)
                extractors[channel.id] = (
                    Extractor(channel.topic, schema.name, roles, signal_map), decode
                )
            extractor, decode = extractors[channel.id]
            try:
                decoded = decode(message.data)
            except Exception as error:  # the decoder raises anything, struct.error to IndexError
                raise InputFileError(
                    f'{file}: a message on {channel.topic} does not decode: {error}'
                ) from error
            for role, time_ns, value in extractor.samples(decoded, message.log_time):
                rows.extend(joiner.add(role, time_ns, value))
        found.update(channel.topic for channel in reader.channels.values())
        problems += [reader.problem] if reader.problem else []
        problems += [
            f'{file}: {extractor.non_finite} value(s) on {extractor.topic} are not finite '
            '(inf or NaN) and were left out'
            for extractor, _ in extractors.values()
            if extractor.non_finite
        ]
    rows.extend(joiner.finish())
    for role in required:
        if signal_map.topics[role] not in found and reader.problem:
            raise InputFileError(
                f'{reader.problem}. Nothing of {signal_map.topics[role]} ({role}) could be read '
                'before the end: no chunk of the file is complete'
            )
        if signal_map.topics[role] not in found:
            raise InputFileError(
                f'{path} has no topic {signal_map.topics[role]} ({role}); its topics: '
                f'{", ".join(sorted(found)) or "none"} '
                f'(map another with --topic-{role.replace("_", "-")})'
            )
    if not rows:
        raise InputFileError(
            f'{path}: no sample has all of {", ".join(required)} (nothing to analyse)'
        )
    column = {
        role: np.array([np.nan if row.get(role) is None else row[role] for _, row in rows])
        for role in (
            'supply_pressure', 'main_valve', 'pilot_poppet', 'inlet_flow', 'tank_pressure',
            'relief_flow',
        )
    }
    flow_times = [row['times'].get('inlet_flow', time_ns) for time_ns, row in rows]
    return Recording(
        np.array([seconds(time_ns) for time_ns, _ in rows]),
        problem='; '.join(problems) or None,
        inlet_flow_time=np.array([seconds(time_ns) for time_ns in flow_times]),
        events=events,
        **column,
    )


def setting_event(settings, decode, data):
    """
    Return [(time [s], what)] if a message changes settings, else [].

    settings: a SettingChanges (fault_status messages) or a ParameterChanges (parameter
    events).
    """
    try:
        message = decode(data)
    except Exception:  # noqa: B902 (a message that does not decode is no event)
        return []
    if isinstance(settings, ParameterChanges):
        event = settings.update(message)
    else:
        stamp = message.header.stamp
        event = settings.update(stamp.sec + stamp.nanosec * 1e-9, {
            pair.key: pair.value for part in message.status for pair in part.values})
    return [event] if event else []


def decoder_for(path, channel, schema, decoder_factories):
    """Return the decode function of a channel of file path: the first factory's that has one."""
    for factory in decoder_factories:
        decode = factory.decoder_for(channel.message_encoding, schema)
        if decode is not None:
            return decode
    raise InputFileError(
        f'{path}: topic {channel.topic} is not a ROS 2 message with a ros2msg schema '
        f"(encoding '{channel.message_encoding}')"
    )


def bag_topics(path):
    """{topic: type name} of every channel of a bag (an MCAP file or a bag folder)."""
    topics = {}
    for file in bag_files(path):
        reader = BagReader(file)
        for _ in reader.messages(topics=()):  # records every channel, yields no message
            pass
        topics.update(
            {c.topic: reader.schemas[c.schema_id].name for c in reader.channels.values()
             if c.schema_id in reader.schemas}
        )
    return topics


def detect_namespace(path, roles):
    """
    Return the namespace of valve_node's topics in a bag, for roles left at their defaults.

    '' when the root has them (or roles is empty, or no namespace has them); the one
    namespace whose supply_pressure (FluidPressure) and applied_inlet_flow (JointState)
    the bag holds; raises InputFileError naming them when several namespaces do.
    """
    if not roles:
        return ''
    topics = bag_topics(path)
    namespaces = sorted(
        topic[: -len('/' + ROLE['supply_pressure'].topic)]
        for topic, type_name in topics.items()
        if topic.endswith('/' + ROLE['supply_pressure'].topic)
        and type_name == FLUID_PRESSURE
        and topics.get(topic.rsplit('/', 1)[0] + '/' + ROLE['inlet_flow'].topic) == JOINT_STATE
    )
    if not namespaces or '' in namespaces:
        return ''
    if len(namespaces) > 1:
        raise InputFileError(
            f"{path} holds valve_node's topics under {len(namespaces)} namespaces: "
            f'{", ".join(namespaces)}; choose one with --namespace'
        )
    return namespaces[0]
