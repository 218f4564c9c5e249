"""Write a rosbag2 bag directory (mcap storage) that Jazzy's rosbag2 and rosbags read.

    with BagWriter('run1', compression='zstd') as bag:
        bag.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [metadata.qos()])
        bag.write('/joint_states', cdr_bytes, recv_ns, pub_ns)

Layout as ``ros2 bag record -s mcap`` (Jazzy) leaves it: ``<dir>/<dir>_0.mcap`` and
``<dir>/metadata.yaml`` (version 9, metadata.metadata_yaml). In the mcap file: profile ``ros2``;
one schema per type, encoding ``ros2msg`` with the full text (the type and every nested
definition, interfaces.full_text); one channel per topic, message encoding ``cdr``, metadata
``offered_qos_profiles`` (version 9 YAML) and ``topic_type_hash`` (RIHS01); messages with log
time = receive time and publish time = send time; at close a ``rosbag2`` metadata record with
the serialized metadata, and the summary (indexes, statistics).

Crash safety: metadata.yaml is written when the bag opens and again whenever a topic is added
(atomically, marked in custom_data as in progress), and rewritten with the final counts at
close. Chunks are closed and handed to the OS at least every ``flush_period`` seconds, so a
process that dies loses at most that much; reader.open_bag reads such a cut file up to its last
complete chunk. Optional zstd chunk compression (``compression='zstd'``), which rosbag2 calls
the storage's own compression: metadata's compression fields stay empty, as rosbag2 leaves them.
"""
from __future__ import annotations

import os
from pathlib import Path
import threading
import time

from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer
from rosbags.interfaces import Qos

from cobot_calib_ros.bags import interfaces
from cobot_calib_ros.bags.errors import BagError
from cobot_calib_ros.bags.metadata import (DEFAULT_DISTRO, IN_PROGRESS_KEY, IN_PROGRESS_VALUE,
                                           BagRecord, TopicRecord, metadata_yaml, qos_text)

METADATA_FILE = 'metadata.yaml'
COMPRESSIONS = {None: CompressionType.NONE, '': CompressionType.NONE, 'none': CompressionType.NONE,
                'zstd': CompressionType.ZSTD}
CHUNK_SIZE = 1 << 20        # [bytes] a chunk is closed when it grows past this ...
FLUSH_PERIOD = 1.0          # [s] ... or when it is this old
LIBRARY = f'cobot_calib_ros bag writer; {LIBRARY_IDENTIFIER}'


class _Topic:
    __slots__ = ('record', 'channel_id')

    def __init__(self, record: TopicRecord, channel_id: int) -> None:
        self.record = record
        self.channel_id = channel_id


class BagWriter:
    """One rosbag2 bag directory being written; not reusable once closed."""

    def __init__(self, path: str | os.PathLike, *, compression: str | None = None,
                 chunk_size: int = CHUNK_SIZE, flush_period: float = FLUSH_PERIOD,
                 ros_distro: str | None = None) -> None:
        if compression not in COMPRESSIONS:
            raise BagError(f'compression {compression!r} not supported: use zstd or none')
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f'{self.path}: already exists; give a new directory '
                           '(a bag is never written over)')
        try:
            self.path.mkdir(parents=True)
        except OSError as exc:
            raise BagError(f'{self.path}: cannot create the bag directory: {exc.strerror}') \
                from None
        self.file_name = f'{self.path.name}_0.mcap'
        self.flush_period = flush_period
        self._lock = threading.Lock()
        self._topics: dict[str, _Topic] = {}
        self._schemas: dict[str, int] = {}
        self._store = None
        self._record = BagRecord('mcap', self.file_name, [],
                                 ros_distro=ros_distro or os.environ.get('ROS_DISTRO')
                                 or DEFAULT_DISTRO)
        self._file = open(self.path / self.file_name, 'wb')
        self._mcap = Writer(self._file, chunk_size=chunk_size,
                            compression=COMPRESSIONS[compression])
        self._mcap.start(profile='ros2', library=LIBRARY)
        self._file.flush()
        self._next_flush = time.monotonic() + flush_period
        self.closed = False
        self._write_metadata(final=False)

    # -- topics and messages ----------------------------------------------------------------

    @property
    def topics(self) -> dict[str, TopicRecord]:
        return {name: t.record for name, t in self._topics.items()}

    @property
    def message_count(self) -> int:
        return self._record.message_count

    def add_topic(self, name: str, msgtype: str, offered_qos: list[Qos] = (),
                  type_hash: str | None = None, definition: str | None = None,
                  serialization_format: str = 'cdr') -> None:
        """Declare a topic before its first message. ``definition`` (ros2msg text) and
        ``type_hash`` default to the installed interface's (interfaces.full_text/type_hash)."""
        with self._lock:
            self._check_open()
            known = self._topics.get(name)
            if known is not None:
                if known.record.type != msgtype:
                    raise BagError(f'{self.path}: topic {name} is already recorded as '
                                   f'{known.record.type}, not {msgtype}')
                return
            record = TopicRecord(name, msgtype, list(offered_qos),
                                 type_hash if type_hash is not None else self._hash(msgtype),
                                 serialization_format)
            channel_id = self._mcap.register_channel(
                topic=name, message_encoding=serialization_format,
                schema_id=self._schema(msgtype, definition),
                metadata={'offered_qos_profiles': qos_text(record.offered_qos),
                          'topic_type_hash': record.type_hash})
            self._topics[name] = _Topic(record, channel_id)
            self._record.topics.append(record)
            self._write_metadata(final=False)

    def write(self, topic: str, data: bytes, recv_ns: int, pub_ns: int | None = None) -> None:
        """One serialized (CDR) message, received at ``recv_ns`` and sent at ``pub_ns``."""
        with self._lock:
            entry = self._topics.get(topic)
            if entry is None or self.closed:
                self._check_open()
                raise BagError(f'{self.path}: topic {topic} was not added before its message')
            self._mcap.add_message(entry.channel_id, recv_ns, data,
                                   recv_ns if pub_ns is None else pub_ns)
            entry.record.count += 1
            record = self._record
            if record.start_ns is None or recv_ns < record.start_ns:
                record.start_ns = recv_ns
            if record.end_ns is None or recv_ns > record.end_ns:
                record.end_ns = recv_ns
            if time.monotonic() >= self._next_flush:
                self._flush_locked()

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS (a crash keeps it)."""
        with self._lock:
            if not self.closed:
                self._flush_locked()

    def close(self) -> None:
        """Finish the mcap file (summary, indexes) and write the final metadata.yaml."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            self._record.custom_data = {}
            self._mcap.add_metadata('rosbag2', {'serialized_metadata': metadata_yaml(
                self._record, top_level=False)})
            self._mcap.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            self._write_metadata(final=True)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- internals ----------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self.closed:
            raise BagError(f'{self.path}: the bag is closed')

    def _flush_locked(self) -> None:
        self._mcap.flush()
        self._next_flush = time.monotonic() + self.flush_period

    def _typestore(self):
        if self._store is None:
            self._store = interfaces.typestore()
        return self._store

    def _hash(self, msgtype: str) -> str:
        found = interfaces.installed_type_hash(msgtype)
        return found or interfaces.type_hash(msgtype, self._typestore())

    def _schema(self, msgtype: str, definition: str | None) -> int:
        """The schema id of a type."""
        if msgtype in self._schemas:
            return self._schemas[msgtype]
        if definition is None:
            try:
                definition = interfaces.full_text(msgtype)
            except (interfaces.DefinitionNotFound, ValueError):
                definition = self._generated_definition(msgtype)
        # no definition known: a schema with an empty encoding (mcap's "no schema"); rosbag2
        # writes "unknown", which rosbags does not read, and schema id 0 loses the type name
        schema_id = self._mcap.register_schema(
            name=msgtype, encoding='' if definition is None else 'ros2msg',
            data=b'' if definition is None else definition.encode())
        self._schemas[msgtype] = schema_id
        return schema_id

    def _generated_definition(self, msgtype: str) -> str | None:
        """A ros2msg text rosbags generates from its typestore (no .msg installed)."""
        try:
            return self._typestore().generate_msgdef(msgtype, ros_version=2)[0]
        except Exception:  # noqa: BLE001 - unknown to the typestore too: no schema
            return None

    def _write_metadata(self, final: bool) -> None:
        record = self._record
        record.custom_data = {} if final else {IN_PROGRESS_KEY: IN_PROGRESS_VALUE}
        target = self.path / METADATA_FILE
        temporary = target.with_name(METADATA_FILE + '.tmp')
        with open(temporary, 'w') as out:
            out.write(metadata_yaml(record))
            out.flush()
            if final:
                os.fsync(out.fileno())
        os.replace(temporary, target)
        if final:
            _fsync_dir(self.path)


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
