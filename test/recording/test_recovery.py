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
Damaged recordings: diagnosed as truncated or corrupt with where, repaired like `mcap recover`.

The repaired files are read with rosbags (a seeking, summary-based reader) as well.
"""

from pathlib import Path
import re
import resource
import signal
import subprocess
import sys
import time

from hostile_inputs import make_sparse_mcap
from mcap.reader import make_reader
import pytest
from rosbags.highlevel import AnyReader
from valve_harness import flushed
from valve_sim.core.errors import InputFileError
from valve_sim.recording.bag import BagReader
from valve_sim.recording.mcap_scan import diagnose
from valve_sim.recording.recovery import repair
from valve_sim.recording.signal_reader import read_recording
from valve_sim.ros import node_command
from valve_sim.ros.replay import Replay
import yaml


REPO = Path(__file__).resolve().parents[2]
REFERENCE_BAG = REPO / 'bags' / 'reference_step.mcap'
TIMEOUT = 60.0  # [s] for anything that waits on another process


def valve_sim(*args, cwd=None):
    """Run `valve-sim ARGS` in its own process; return the CompletedProcess (text output)."""
    return subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', *map(str, args)],
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
        cwd=cwd,
    )


def rosbags_messages(path):
    """Return [(topic, log_time, data)] as rosbags reads a file or bag folder (needs summaries)."""
    with AnyReader([Path(path)]) as reader:
        return [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]


def messages_in_order(path):
    """Return [(topic, log_time, data)] of a complete file in file order (the mcap library)."""
    with open(path, 'rb') as stream:
        return [
            (channel.topic, message.log_time, message.data)
            for _, channel, message in make_reader(stream).iter_messages(log_time_order=False)
        ]


def cuts(size, count=20):
    """Return count offsets from 449 bytes (inside the first chunk) to one byte short of size."""
    return sorted({449 + (size - 450) * k // (count - 1) for k in range(count)})


def test_a_file_cut_anywhere_is_truncated_and_repaired_to_what_it_holds(tmp_path):
    whole = REFERENCE_BAG.read_bytes()
    everything = messages_in_order(REFERENCE_BAG)
    kept_before = 0
    for cut in cuts(len(whole)):
        damaged, repaired = tmp_path / f'cut{cut}.mcap', tmp_path / f'cut{cut}.repaired.mcap'
        damaged.write_bytes(whole[:cut])
        scan = diagnose(damaged)
        assert scan.truncated and f'ends at byte {cut}' in scan.damage, scan.damage
        try:
            problem = read_recording(damaged).problem
        except InputFileError as error:
            problem = str(error)
        assert 'truncated' in problem and f'byte {cut}' in problem, problem
        report = repair(damaged, repaired)
        kept = rosbags_messages(repaired)
        assert len(kept) == report.messages >= kept_before, 'more file, no fewer messages'
        assert sorted(kept) == sorted(everything[: len(kept)]), 'what it held, unchanged'
        kept_before = len(kept)
    assert kept_before > 0.9 * len(everything), 'a cut near the end keeps nearly everything'


def test_analyse_says_truncated_and_where_for_a_file_cut_before_its_first_chunk(tmp_path):
    """
    The issue's reproduction: head -c 449000 bags/reference_step.mcap > t.mcap.

    analyse reads the file as repair does (mcap_scan.Scan): what the chunk cut short
    holds, with the warning that says where the file ends; the repaired copy gives the
    same analysis.
    """
    cut = tmp_path / 't.mcap'
    cut.write_bytes(REFERENCE_BAG.read_bytes()[:449000])
    analysed = valve_sim('analyse', cut)
    assert analysed.returncode == 0, analysed.stderr
    assert 'truncated' in analysed.stderr and 'ends at byte 449000' in analysed.stderr
    assert 'valve-sim repair' in analysed.stderr and 'Traceback' not in analysed.stderr
    result = valve_sim('repair', cut)
    assert result.returncode == 0, result.stderr
    kept = rosbags_messages(tmp_path / 't.repaired.mcap')
    assert f'kept {len(kept)} messages' in result.stdout and len(kept) > 4000, result.stdout
    assert sorted(kept) == sorted(messages_in_order(REFERENCE_BAG)[: len(kept)])
    repaired = valve_sim('analyse', tmp_path / 't.repaired.mcap')
    assert repaired.stdout == analysed.stdout and repaired.stderr == ''


def test_a_complete_file_is_copied_whole_and_never_overwritten(tmp_path):
    copy = tmp_path / 'copy.mcap'
    report = repair(REFERENCE_BAG, copy)
    assert report.damage is None and diagnose(copy).damage is None
    assert sorted(rosbags_messages(copy)) == sorted(messages_in_order(REFERENCE_BAG))
    with pytest.raises(InputFileError, match='being repaired'):
        repair(copy, copy)


def test_a_corrupt_chunk_is_diagnosed_where_it_is(tmp_path):
    data = bytearray(REFERENCE_BAG.read_bytes())
    quarter = len(data) // 4
    data[quarter:quarter + 16] = bytes(16)  # inside the (only) chunk
    damaged = tmp_path / 'damaged.mcap'
    damaged.write_bytes(bytes(data))
    scan = diagnose(damaged)
    assert not scan.truncated and 'fails its CRC' in scan.damage, scan.damage
    assert re.search(r'the chunk at byte \d+', scan.damage)
    with pytest.raises(InputFileError, match='corrupt.*valve-sim repair'):
        list(BagReader(damaged).messages())


# --- recordings that crashed ---------------------------------------------------------------------


def start_analyser(folder, file_size_limit=None):
    """Start analyser_node recording into folder; a file size limit [bytes] acts as a full disk."""

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write beyond it fails (EFBIG)
        resource.setrlimit(resource.RLIMIT_FSIZE, (file_size_limit, file_size_limit))

    return subprocess.Popen(
        node_command('analyser_node', parameters={'output_dir': folder, 'flush_interval': 0.1}),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=limit if file_size_limit else None,
    )


def wait_for(condition, what):
    deadline = time.monotonic() + TIMEOUT
    while not condition():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        time.sleep(0.05)


def test_kill_9_mid_recording_then_repair_keeps_at_least_every_flushed_message(
    node, tick_waveforms, tmp_path
):
    analyser = start_analyser(tmp_path)
    try:
        replay = Replay(node)
        replay.wait_for_subscribers(timeout=TIMEOUT)
        wait_for(lambda: list(tmp_path.glob('*.mcap')), 'the bag file')
        bag = next(tmp_path.glob('*.mcap'))
        replay.publish(tick_waveforms, time.time_ns(), every=2)
        wait_for(lambda: flushed(bag) > 0, 'a flushed chunk')
        analyser.kill()  # kill -9 while it records: no summary, maybe an open chunk
        analyser.communicate(timeout=TIMEOUT)
    finally:
        if analyser.poll() is None:
            analyser.kill()
    count = flushed(bag)
    result = valve_sim('repair', bag, '-o', 'fixed.mcap', cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert len(rosbags_messages(tmp_path / 'fixed.mcap')) >= count > 0


def test_a_full_disk_stops_the_analyser_naming_its_file_and_the_repair(
    node, tick_waveforms, tmp_path
):
    analyser = start_analyser(tmp_path, file_size_limit=150_000)
    try:
        replay = Replay(node)
        replay.wait_for_subscribers(timeout=TIMEOUT)
        deadline = time.monotonic() + TIMEOUT
        while analyser.poll() is None:  # record until the file reaches the limit
            assert time.monotonic() < deadline, 'the analyser never hit its full disk'
            replay.publish(tick_waveforms, time.time_ns(), every=5)
        log = analyser.communicate(timeout=TIMEOUT)[0]
    finally:
        if analyser.poll() is None:
            analyser.kill()
    bag = next(tmp_path.glob('*.mcap'))
    assert analyser.returncode == 1, log
    assert f'cannot write {bag}' in log and 'File too large' in log, log
    assert f'valve-sim repair {bag}' in log and 'Traceback' not in log, log
    report = repair(bag, tmp_path / 'fixed.mcap')
    assert len(rosbags_messages(tmp_path / 'fixed.mcap')) == report.messages >= flushed(bag) > 0


def catches_sigterm(process):
    """Return whether the process has a SIGTERM handler: valve_sim.ros's, set as it is imported."""
    status = Path(f'/proc/{process.pid}/status').read_text()
    caught = int(re.search(r'^SigCgt:\s*([0-9a-f]+)$', status, re.MULTILINE).group(1), 16)
    return bool(caught >> (signal.SIGTERM - 1) & 1)


@pytest.mark.parametrize('delay', [0.0, 0.1, 0.3, 0.6, 1.0, 2.0])
def test_sigint_at_any_point_of_start_up_leaves_no_traceback(tmp_path, delay):
    """
    SIGINT at delay [s] after the node's code began (its handlers set): no traceback, 0 or 130.

    Before that, the interpreter is still starting (site, the import system) and a
    SIGINT ends it with CPython's own message: that part is no program's to handle.
    """
    analyser = start_analyser(tmp_path)
    try:
        wait_for(lambda: catches_sigterm(analyser), "valve_sim.ros's start-up handlers")
        time.sleep(delay)  # the stimulus: a signal at this point of start-up
        analyser.send_signal(signal.SIGINT)
        log = analyser.communicate(timeout=TIMEOUT)[0]
    finally:
        if analyser.poll() is None:
            analyser.kill()
    assert 'Traceback' not in log and 'KeyboardInterrupt' not in log, log
    # 0: stopped cleanly; 130: left quietly while starting up
    assert analyser.returncode in (0, 128 + signal.SIGINT), log


def test_a_bag_folder_is_repaired_file_by_file_into_a_new_bag_folder(tmp_path):
    """
    `valve-sim repair FOLDER`: each file repaired, and a metadata.yaml for the new folder.

    A split recording that crashed: rig_0.mcap complete, rig_1.mcap cut short, no
    metadata.yaml (rosbag2 writes it at the end). rosbags reads the repaired folder.
    """
    folder = tmp_path / 'rig'
    folder.mkdir()
    (folder / 'rig_0.mcap').write_bytes(REFERENCE_BAG.read_bytes())
    (folder / 'rig_1.mcap').write_bytes(REFERENCE_BAG.read_bytes()[:449000])
    result = valve_sim('repair', folder)
    assert result.returncode == 0, result.stderr
    repaired = tmp_path / 'rig_repaired'
    cut_short = rosbags_messages(repaired / 'rig_1.mcap')
    assert f'kept {len(cut_short)} messages' in result.stdout, result.stdout
    assert len(cut_short) > 4000, 'the chunk cut short is salvaged'
    everything = messages_in_order(REFERENCE_BAG)
    assert sorted(rosbags_messages(repaired)) == sorted(everything + everything[: len(cut_short)])
    metadata = yaml.safe_load((repaired / 'metadata.yaml').read_text())
    bag = metadata['rosbag2_bagfile_information']
    assert bag['relative_file_paths'] == ['rig_0.mcap', 'rig_1.mcap']
    assert bag['message_count'] == len(everything) + len(cut_short)
    assert [f['message_count'] for f in bag['files']] == [len(everything), len(cut_short)]
    kept = everything + cut_short
    assert {
        t['topic_metadata']['name']: t['message_count'] for t in bag['topics_with_message_count']
    } == {topic: sum(1 for t, _, _ in kept if t == topic) for topic, _, _ in kept}
    with AnyReader([repaired]) as reader:
        assert reader.message_count == len(kept)
        assert reader.start_time == min(t for _, t, _ in kept)
        assert reader.end_time == max(t for _, t, _ in kept) + 1  # rosbags: one past the last
    assert (folder / 'rig_1.mcap').stat().st_size == 449000, 'the source is only read'
    assert not (folder / 'metadata.yaml').exists()


# --- corrupt is not truncated, and a hole is not a hang -----------------------------------------


def many_chunks(path, messages=3000, chunk_size=8192):
    """Write a closed bag of supply-pressure messages in small chunks; return the chunk offsets."""
    from valve_sim.recording.bag import BagWriter
    from valve_sim.recording.mcap_scan import RECORD_HEADER

    bag = BagWriter(path, chunk_size=chunk_size)
    bag.add_topic('/supply_pressure', 'sensor_msgs/msg/FluidPressure')
    for k in range(messages):
        bag.write_message('/supply_pressure', {'fluid_pressure': float(k)}, k, k)
    bag.close()
    data, offset, chunks = path.read_bytes(), 8, []
    while offset < len(data):
        opcode, length = RECORD_HEADER.unpack_from(data, offset)
        if opcode == 6:
            chunks.append(offset)
        if opcode == 2:
            return chunks
        offset += RECORD_HEADER.size + length
    return chunks


def log_times(path):
    return [message.log_time for _, _, message in BagReader(path).messages()]


def flipped_chunk_length(path, bit, cut=False):
    """
    Write many_chunks() to path with one bit of the 4th chunk's length flipped.

    cut: the file also ends 3 chunks early (no footer). Returns (the chunks' offsets,
    the log times of every message written).
    """
    chunks = many_chunks(path)
    everything = log_times(path)
    data = bytearray(path.read_bytes())
    data[chunks[3] + 1 + bit // 8] ^= 1 << bit % 8
    path.write_bytes(bytes(data[:chunks[-3]] if cut else data))
    return chunks, everything


@pytest.mark.parametrize('bit', [0, 17, 40])  # the length field's low, middle and high bits
@pytest.mark.parametrize('cut', [False, True])  # a file with its footer, or one cut short
def test_a_bit_flip_in_a_chunk_length_is_corrupt_and_repair_keeps_every_intact_chunk(
    tmp_path, bit, cut
):
    path = tmp_path / 'flipped.mcap'
    chunks, everything = flipped_chunk_length(path, bit, cut)
    scan = diagnose(path)
    assert f'is corrupt at byte {chunks[3]}' in scan.damage or (
        f'the chunk at byte {chunks[3]} fails its CRC' in scan.damage
    ), scan.damage
    report = repair(path, tmp_path / 'repaired.mcap')
    kept = log_times(tmp_path / 'repaired.mcap')
    lost = set(everything) - set(kept)
    assert set(kept) <= set(everything) and kept == sorted(kept)
    if not cut:  # only the length field is damaged: the chunk itself is read past it
        assert not lost, report.summary()
    assert len(lost) <= 4 * len(everything) / len(chunks), (len(lost), report.summary())
    with pytest.raises(InputFileError, match='damaged'):
        log_times(path)  # analyse says what repair says


def test_analyse_gives_a_sparse_hole_the_verdict_of_repair_as_fast(tmp_path):
    """MCAP magic, then a 2 GiB hole: analyse spun for minutes while repair answered at once."""
    path = tmp_path / 'hole.mcap'
    make_sparse_mcap(path)
    analysed, repaired = valve_sim('analyse', path), valve_sim('repair', path)
    verdict = f'{path} is corrupt at byte 8: no MCAP record starts there'
    assert analysed.returncode == repaired.returncode == 1
    assert verdict in analysed.stderr and verdict in repaired.stderr, (analysed, repaired)


def test_random_damage_of_a_bag_keeps_every_intact_chunk(tmp_path):
    """
    Fuzz: 40 seeded damages of 1-3 bytes, half of them in the records' framing.

    Wherever the damage, repair keeps the messages of every chunk it did not touch (a
    corrupt record once made it drop every later chunk), and analyse's reader gives
    the same verdict: a refusal naming the damage, never a crash.
    """
    import random

    source = tmp_path / 'source.mcap'
    chunks = many_chunks(source, messages=1500, chunk_size=4096)
    with open(source, 'rb') as stream:
        indexes = make_reader(stream).get_summary().chunk_indexes
    ranges = [(c.chunk_start_offset, c.chunk_start_offset + c.chunk_length,
               range(c.message_start_time, c.message_end_time + 1)) for c in indexes]
    data, rng = source.read_bytes(), random.Random(25)
    for number in range(40):
        damaged, positions = bytearray(data), []
        for _ in range(rng.randint(1, 3)):
            framing = rng.random() < 0.5
            at = rng.choice(chunks) + rng.randrange(9) if framing else rng.randrange(
                chunks[0], ranges[-1][1]
            )
            damaged[at] ^= rng.randrange(1, 256)
            positions.append(at)
        path = tmp_path / f'damaged{number}.mcap'
        path.write_bytes(bytes(damaged))
        try:
            log_times(path)
        except InputFileError as error:
            assert 'damaged' in str(error)
        repair(path, tmp_path / f'repaired{number}.mcap')
        kept = set(log_times(tmp_path / f'repaired{number}.mcap'))
        intact = {
            time for start, end, times in ranges
            if not any(start <= at < end for at in positions) for time in times
        }
        assert intact <= kept, (number, positions, len(intact - kept))
