"""Damaged, cut and odd bags: a BagError that names the file, or (not strict) everything up to
the last complete chunk; a recording killed mid-way reads up to its last flushed message."""
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys

from mcap.reader import make_reader
import pytest

from bagutil import RELIABLE, cdr, joint_state
from cobot_calib_ros.bags.errors import BagError
from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.bags.writer import BagWriter

JS = 'sensor_msgs/msg/JointState'
T0 = 1_795_000_000_000_000_000


def chunked_bag(path: Path, count: int = 60, per_chunk: int = 10, compression=None) -> list:
    """A bag whose chunks each hold ``per_chunk`` messages; the raw messages written."""
    written = []
    with BagWriter(path, compression=compression, flush_period=1e9) as bag:
        bag.add_topic('/joint_states', JS, [RELIABLE])
        for i in range(count):
            data = cdr(joint_state(i))
            bag.write('/joint_states', data, T0 + i * 1_000_000)
            written.append(data)
            if i % per_chunk == per_chunk - 1:
                bag.flush()
    return written


def storage(path: Path) -> Path:
    return next(path.glob('*.mcap'))


def chunk_ends(path: Path) -> list[int]:
    """The end offset of each chunk of a closed bag, in file order."""
    with open(storage(path), 'rb') as f:
        summary = make_reader(f).get_summary()
    return sorted(c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes)


def copy_cut(src: Path, dst: Path, size: int) -> Path:
    shutil.copytree(src, dst)
    with open(storage(dst), 'r+b') as f:
        f.truncate(size)
    return dst


def test_no_such_path(tmp_path):
    with pytest.raises(BagError, match=f'{tmp_path}/nope: no such bag'):
        open_bag(tmp_path / 'nope')


def test_a_directory_without_storage_files(tmp_path):
    (tmp_path / 'notes.txt').write_text('x')
    with pytest.raises(BagError, match=f'{tmp_path}: not a rosbag2 bag: no .mcap or .db3'):
        open_bag(tmp_path)


def test_missing_metadata(tmp_path):
    written = chunked_bag(tmp_path / 'b', 20)
    (tmp_path / 'b' / 'metadata.yaml').unlink()
    with pytest.raises(BagError, match=r'b/metadata.yaml: missing .*without strict'):
        open_bag(tmp_path / 'b', strict=True)
    with open_bag(tmp_path / 'b') as bag:
        assert [m.rawdata for m in bag.messages()] == written
        assert not bag.complete and 'metadata.yaml: missing' in bag.warnings[0]
        assert bag.topics['/joint_states'].offered_qos == [RELIABLE]   # from the channel


def test_unreadable_metadata(tmp_path):
    written = chunked_bag(tmp_path / 'b', 20)
    (tmp_path / 'b' / 'metadata.yaml').write_text('rosbag2_bagfile_information: [unclosed\n')
    with pytest.raises(BagError, match=r'b/metadata.yaml: not a rosbag2 metadata file'):
        open_bag(tmp_path / 'b', strict=True)
    with open_bag(tmp_path / 'b') as bag:
        assert len(list(bag.messages())) == len(written)


def test_metadata_naming_a_missing_file(tmp_path):
    chunked_bag(tmp_path / 'b', 20)
    storage(tmp_path / 'b').rename(tmp_path / 'b' / 'elsewhere.bin')
    with pytest.raises(BagError, match=r'b/b_0.mcap: listed in metadata.yaml but missing'):
        open_bag(tmp_path / 'b', strict=True)
    with pytest.raises(BagError, match=r'b: not a rosbag2 bag'):
        open_bag(tmp_path / 'b')


def test_truncated_mcap_strict_names_the_file(tmp_path):
    chunked_bag(tmp_path / 'b')
    size = storage(tmp_path / 'b').stat().st_size
    cut = copy_cut(tmp_path / 'b', tmp_path / 'cut', size - 100)
    with pytest.raises(BagError, match=r'cut/b_0.mcap: cut short or damaged .*without strict'):
        open_bag(cut, strict=True)


def test_truncated_anywhere_reads_every_complete_chunk(tmp_path):
    """Cut at many points: the reader returns exactly the messages of the chunks that end
    before the cut (a prefix of what was written), never garbage, never another error."""
    written = chunked_bag(tmp_path / 'b', 60, 10)
    ends = chunk_ends(tmp_path / 'b')
    assert len(ends) == 6
    size = storage(tmp_path / 'b').stat().st_size
    cuts = sorted({*range(40, size, 97), *ends, *(e - 1 for e in ends), *(e + 1 for e in ends)})
    for n, cut in enumerate(c for c in cuts if c < size - 20):
        path = copy_cut(tmp_path / 'b', tmp_path / f'cut{n}', cut)
        expected = 10 * sum(1 for e in ends if e <= cut)
        try:
            with open_bag(path) as bag:
                got = [m.rawdata for m in bag.messages()]
                assert bag.message_count == len(got)
        except BagError as exc:                     # only when the header itself is cut
            assert f'cut{n}/b_0.mcap: cut short or damaged before its first' in str(exc)
            assert expected == 0
            continue
        assert got == written[:expected], f'cut at {cut}'
        assert not bag.complete and any('b_0.mcap' in w for w in bag.warnings)


def test_zstd_chunks_recover_too(tmp_path):
    written = chunked_bag(tmp_path / 'b', 30, 10, compression='zstd')
    ends = chunk_ends(tmp_path / 'b')
    with open_bag(copy_cut(tmp_path / 'b', tmp_path / 'cut', ends[1] + 30)) as bag:
        assert [m.rawdata for m in bag.messages()] == written[:20]


def test_wrong_magic_and_garbage_files(tmp_path):
    chunked_bag(tmp_path / 'b', 10)
    storage(tmp_path / 'b').write_bytes(b'this is not an mcap file at all' * 10)
    for strict in (False, True):
        with pytest.raises(BagError, match=r'b/b_0.mcap: not an MCAP file'):
            open_bag(tmp_path / 'b', strict=strict)
    storage(tmp_path / 'b').write_bytes(b'')
    with pytest.raises(BagError, match=r'b/b_0.mcap: empty; it is damaged or not a bag file'):
        open_bag(tmp_path / 'b')
    db = tmp_path / 'garbage.db3'
    db.write_bytes(b'\x00' * 4096)
    with pytest.raises(BagError, match=r'garbage.db3: not a readable rosbag2 sqlite3 file'):
        open_bag(db)


def test_damaged_chunk_in_a_complete_file(tmp_path):
    chunked_bag(tmp_path / 'b', 30, 10)
    ends = chunk_ends(tmp_path / 'b')
    path = storage(tmp_path / 'b')
    data = bytearray(path.read_bytes())
    middle = (ends[0] + ends[1]) // 2              # inside the second chunk's messages
    data[middle:middle + 8] = b'\xff' * 8
    path.write_bytes(bytes(data))
    with open_bag(tmp_path / 'b') as bag:          # the summary is intact: it opens ...
        with pytest.raises(BagError, match=r'b: damaged: .*checksum'):
            list(bag.messages())                    # ... and says where reading failed


def test_unknown_type(tmp_path):
    with BagWriter(tmp_path / 'b') as bag:
        bag.add_topic('/x', 'foo_msgs/msg/Bar', [RELIABLE])
        bag.write('/x', b'\x00\x01\x00\x00\x07\x00\x00\x00', T0)
    with open_bag(tmp_path / 'b') as bag:
        message = next(bag.messages())             # raw bytes need no type
        with pytest.raises(BagError, match=r'b: unknown message type foo_msgs/msg/Bar'):
            bag.deserialize(message.rawdata, message.msgtype)
        with pytest.raises(BagError, match=r'foo_msgs/msg/Bar \(topic /x\): it is not '
                                           r'installed here'):
            bag.require_types()


def test_unknown_topic(tmp_path):
    chunked_bag(tmp_path / 'b', 10)
    with open_bag(tmp_path / 'b') as bag:
        with pytest.raises(BagError, match=r'no topic /nope in the bag; it has /joint_states'):
            list(bag.messages(['/nope']))


def test_an_empty_bag_cannot_be_replayed(tmp_path):
    from cobot_calib_ros.bags.player import BagPlayer
    with BagWriter(tmp_path / 'empty') as bag:
        bag.add_topic('/joint_states', JS, [RELIABLE])
    with open_bag(tmp_path / 'empty') as bag:
        with pytest.raises(BagError, match=r'empty: no messages to replay'):
            BagPlayer(bag)                          # refused before any rclpy set-up


CRASHER = '''
import sys
sys.path.insert(0, {test_dir!r})
from bagutil import RELIABLE, cdr, joint_state
from cobot_calib_ros.bags.writer import BagWriter
bag = BagWriter({path!r}, flush_period=1e9)
bag.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [RELIABLE])
i = 0
while True:
    bag.write('/joint_states', cdr(joint_state(i)), {t0} + i * 1_000_000)
    i += 1
    if i % 25 == 0:
        bag.flush()
        print(i, flush=True)
'''


def test_a_recording_killed_mid_way_reads_up_to_its_last_flush(tmp_path):
    path = tmp_path / 'killed'
    code = CRASHER.format(test_dir=str(Path(__file__).parent), path=str(path), t0=T0)
    proc = subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE, text=True)
    try:
        flushed = 0
        while flushed < 500:
            flushed = int(proc.stdout.readline())
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    with pytest.raises(BagError, match='killed/metadata.yaml: written while recording'):
        open_bag(path, strict=True)
    with open_bag(path) as bag:
        got = list(bag.messages())
        assert not bag.complete
    assert len(got) >= 500 and len(got) % 25 == 0       # whole flushed chunks, nothing torn
    assert [m.rawdata for m in got] == [cdr(joint_state(i)) for i in range(len(got))]
    assert [m.timestamp_ns for m in got] == [T0 + i * 1_000_000 for i in range(len(got))]
