"""Read rosbag2 bags (mcap or sqlite3; ours or rosbag2's) through rosbags, tolerantly.

    with open_bag('run1') as bag:
        for topic, msgtype, stamp_ns, raw in bag.messages(['/joint_states']):
            msg = bag.deserialize(raw, msgtype)

What ``open_bag`` accepts and how it reads it:
- a bag directory with metadata.yaml: rosbags' rosbag2 Reader (every metadata version up to
  Jazzy's 9, mcap and sqlite3, zstd file/message compression). rosbags matches metadata.yaml's
  topics to the storage's on topic, type *and QoS* and silently yields nothing when they
  disagree (rosbag2's own test bags ``talker`` do: deadline 0 in metadata.yaml, 2147483647 s in
  the storage). Such a topic is matched on topic and type alone here; the QoS shown is the one
  metadata.yaml states.
- a single storage file (``.mcap``, ``.db3``), as ``ros2 bag info`` does.
- what a crash leaves (``strict=False``, the default): no metadata.yaml, a metadata.yaml our
  writer had not finalised, an mcap file without its summary and footer. The storage files are
  then read directly, a cut mcap file sequentially (mcap's StreamReader) up to its last complete
  chunk; ``bag.warnings`` says what was recovered. ``strict=True`` raises BagError instead.

Marks recorded before they had messages of their own (sensor_msgs/JointState on the capture
and probe-average topics) are read through bags.mark_converter: the topic shows the mark's type
(``converted_from`` the recorded one) and its messages come converted.

Every error is a BagError naming the file, the problem and what to do. Messages decode with a
typestore of Jazzy's types plus this project's cobot_calib_msgs and tf2_msgs (interfaces); a
bag's own definitions add only the types that typestore lacks (rosbag2's test bags carry
placeholder definitions of standard types, which must not replace the real ones).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from itertools import chain
import os
from pathlib import Path, PurePath
import struct
from typing import Iterable, Iterator, NamedTuple

from rosbags.interfaces import (Connection, MessageDefinition, MessageDefinitionFormat, Qos)
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import get_types_from_idl, get_types_from_msg
import yaml

from cobot_calib_ros.bags import interfaces, mark_converter
from cobot_calib_ros.bags.errors import BagError
from cobot_calib_ros.bags.metadata import IN_PROGRESS_KEY

METADATA_FILE = 'metadata.yaml'
STORAGE_SUFFIXES = {'.mcap': 'mcap', '.db3': 'sqlite3'}
MCAP_MAGIC = b'\x89MCAP0\r\n'
TIME_MAX = 2**63 - 1

__all__ = ['BagError', 'Bag', 'BagMessage', 'TopicInfo', 'open_bag']


class BagMessage(NamedTuple):
    topic: str
    msgtype: str
    timestamp_ns: int           # receive time (rosbag2's recv_timestamp, mcap log time)
    rawdata: bytes              # serialized CDR, as recorded


@dataclass
class TopicInfo:
    name: str
    type: str
    count: int
    serialization_format: str = 'cdr'
    offered_qos: list[Qos] = field(default_factory=list)
    type_hash: str = ''
    definition: MessageDefinition | None = None
    converted_from: str = ''        # the type recorded, when read through bags.mark_converter


def open_bag(path: str | os.PathLike, strict: bool = False) -> 'Bag':
    """Open a bag directory or a single .mcap/.db3 file; BagError if it cannot be read."""
    return Bag(Path(path), strict)


class Bag:
    """An open bag: what ``ros2 bag info`` shows, its messages, and their decoding."""

    def __init__(self, path: Path, strict: bool = False) -> None:
        self.path = path
        self.strict = strict
        self.warnings: list[str] = []
        self.version: int | None = None
        self.ros_distro = ''
        self.storage_id = ''
        self.compression_format = ''
        self.compression_mode = ''
        self.relative_files: list[str] = []     # as metadata.yaml lists them (or found)
        self.topics: dict[str, TopicInfo] = {}
        self.message_count = 0
        self.start_ns: int | None = None        # first message [ns]; None when empty
        self.end_ns: int | None = None          # last message [ns]
        self.complete = True                    # False: read around a crash or damage
        self._sources: list[_Source] = []
        self._store = None
        self._refused = ''
        self._converters: dict = {}             # topic -> its marks' converter (lazy)
        if not path.exists():
            raise BagError(f'{path}: no such bag (neither a directory nor a file); give the '
                           'directory `cobot-calib record -o` or `ros2 bag record -o` wrote')
        try:
            if path.is_dir():
                self._open_directory()
            else:
                self._open_files([path], metadata=None)
        except BaseException:
            self.close()                       # the storage files opened before the error
            raise
        for topic, msgtype in mark_converter.legacy_topics(self.topics).items():
            info = self.topics[topic]
            info.converted_from, info.type = info.type, msgtype
            info.type_hash, info.definition = interfaces.installed_type_hash(msgtype), None
            self._converters[topic] = None

    # -- public ---------------------------------------------------------------------------------

    @property
    def duration_ns(self) -> int:
        return 0 if self.start_ns is None else self.end_ns - self.start_ns

    @property
    def size_bytes(self) -> int:
        """What ``ros2 bag info`` calls the bag size: the files in the bag directory."""
        if self.path.is_file():
            return self.path.stat().st_size
        return sum(p.stat().st_size for p in self.path.iterdir() if p.is_file())

    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 stop_ns: int | None = None) -> Iterator[BagMessage]:
        """(topic, msgtype, timestamp_ns, rawdata) of the chosen topics (all when None), in
        time order within each storage file; ``start_ns`` <= stamp < ``stop_ns``."""
        wanted = self._wanted(topics)
        stream = chain.from_iterable(s.messages(wanted, start_ns, stop_ns) for s in self._sources)
        if not self._converters.keys() & set(wanted):
            return stream
        return self._converted(stream)

    def select(self, topics: Iterable[str] | None = None) -> list[str]:
        """The topic names chosen (all when None; 'name' means '/name'); BagError for a topic
        the bag does not have."""
        return self._wanted(topics)

    def deserialize(self, rawdata: bytes, msgtype: str):
        """A message as rosbags' dataclass; BagError when its type is unknown or it does not
        decode as that type."""
        store = self.typestore
        if msgtype not in store.fielddefs:
            raise BagError(self._unknown_type(msgtype))
        try:
            return store.deserialize_cdr(rawdata, msgtype)
        except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds
            raise BagError(f'{self.path}: a {msgtype} message does not decode ({exc}); the '
                           'bag was recorded with a different definition of the type') from None

    def require_types(self, topics: Iterable[str] | None = None) -> None:
        """BagError unless every chosen topic's type can be decoded here."""
        for name in self._wanted(topics):
            msgtype = self.topics[name].type
            if msgtype not in self.typestore.fielddefs:
                raise BagError(self._unknown_type(msgtype, name))

    @property
    def typestore(self):
        if self._store is None:
            self._store = self._build_typestore()
        return self._store

    def close(self) -> None:
        for source in self._sources:
            source.close()
        self._sources = []

    def __enter__(self) -> Bag:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _converted(self, stream: Iterator[BagMessage]) -> Iterator[BagMessage]:
        """``stream`` with the legacy marks converted (bags.mark_converter)."""
        for message in stream:
            if message.topic not in self._converters:
                yield message
                continue
            convert = self._converters[message.topic]
            if convert is None:
                convert = self._converters[message.topic] = mark_converter.converter(
                    self.typestore, message.topic)
            try:
                rawdata = convert(message.rawdata)
            except Exception as exc:  # noqa: BLE001 - rosbags' decoding errors alike
                raise BagError(f'{self.path}: a {mark_converter.LEGACY_TYPE} mark on '
                               f'{message.topic} does not convert ({_short(exc)}); the bag may '
                               'be damaged') from None
            yield BagMessage(message.topic, self.topics[message.topic].type,
                             message.timestamp_ns, rawdata)

    # -- opening --------------------------------------------------------------------------------

    def _open_directory(self) -> None:
        meta_path = self.path / METADATA_FILE
        metadata = None
        if not meta_path.exists():
            problem = f'{meta_path}: missing (a recording cut short?)'
            if self.strict:
                raise BagError(problem + '; open the bag without strict to read its storage '
                               'files directly')
            self._recovering(problem + '; reading the storage files directly')
        else:
            metadata = self._load_metadata(meta_path)
            if metadata is not None and _in_progress(metadata):
                problem = (f'{meta_path}: written while recording and never finalised (the '
                           'recording did not close cleanly)')
                if self.strict:
                    raise BagError(problem + '; open the bag without strict to read what '
                                   'its storage files hold')
                self._recovering(problem + '; messages and counts come from the storage files')
            elif metadata is not None and self._open_with_rosbags(metadata):
                return
        warned = len(self.warnings)
        self._open_files(self._storage_files(metadata), metadata)
        if self._refused and len(self.warnings) == warned:
            self._recovering(f'{self.path / METADATA_FILE}: rosbags refused the bag '
                             f'({self._refused}); its storage files were read one by one')

    def _load_metadata(self, meta_path: Path) -> dict | None:
        try:
            data = yaml.safe_load(meta_path.read_text())
            info = data['rosbag2_bagfile_information']
            if not isinstance(info, dict):
                raise TypeError('rosbag2_bagfile_information is not a map')
            return info
        except (OSError, yaml.YAMLError, KeyError, TypeError) as exc:
            problem = f'{meta_path}: not a rosbag2 metadata file ({_short(exc)})'
            if self.strict:
                raise BagError(problem + '; fix or remove it to read the storage files '
                               'directly') from None
            self.warnings.append(problem)
            return None

    def _open_with_rosbags(self, metadata: dict) -> bool:
        """The whole directory through rosbags' Reader; False when it refuses (the caller
        then reads the files one by one, which names the broken one)."""
        try:
            reader = Reader(self.path)
            reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags' and sqlite's errors alike
            if self.strict:
                # find the file at fault, else blame metadata.yaml
                self._open_files(self._storage_files(metadata), metadata)
                self.close()
                raise BagError(f'{self.path / METADATA_FILE}: {_short(exc)}; the storage files '
                               'alone read fine, so check metadata.yaml') from None
            self._refused = _short(exc)
            return False
        self._take_metadata(metadata)
        storage_conns = [c for s in reader.storage.storages for c in s.connections]
        connections = []
        for conn in reader.connections:
            self.topics[conn.topic] = TopicInfo(
                conn.topic, conn.msgtype, conn.msgcount, conn.ext.serialization_format,
                list(conn.ext.offered_qos_profiles), conn.digest or '',
                conn.msgdef if conn.msgdef.format != MessageDefinitionFormat.NONE else None)
            if not any(s.topic == conn.topic and s.msgtype == conn.msgtype and s.ext == conn.ext
                       for s in storage_conns):
                # the QoS pitfall: match the storage's connection on topic and type alone
                match = next((s for s in storage_conns if s.topic == conn.topic
                              and s.msgtype == conn.msgtype), None)
                if match is not None:
                    conn = conn._replace(ext=match.ext)
            connections.append(conn)
        self.message_count = int(metadata.get('message_count', 0))
        start = int(metadata['starting_time']['nanoseconds_since_epoch'])
        duration = int(metadata['duration']['nanoseconds'])
        if self.message_count:
            self.start_ns, self.end_ns = start, start + duration
        self._sources.append(_RosbagsSource(reader, connections))
        return True

    def _take_metadata(self, metadata: dict | None) -> None:
        if metadata is None:
            return
        self.version = metadata.get('version')
        self.ros_distro = metadata.get('ros_distro') or ''
        self.storage_id = metadata.get('storage_identifier') or ''
        self.compression_format = metadata.get('compression_format') or ''
        self.compression_mode = metadata.get('compression_mode') or ''
        self.relative_files = [str(p) for p in metadata.get('relative_file_paths') or []]

    def _storage_files(self, metadata: dict | None) -> list[Path]:
        listed = []
        if metadata is not None:
            for name in metadata.get('relative_file_paths') or []:
                path = self.path / PurePath(str(name)).name
                if path.exists():
                    listed.append(path)
                else:
                    problem = f'{path}: listed in metadata.yaml but missing'
                    if self.strict:
                        raise BagError(problem + '; restore it, or remove metadata.yaml to read '
                                       'the files that are there')
                    self._recovering(problem)
        if listed:
            return listed
        found = sorted(p for p in self.path.iterdir() if p.suffix in STORAGE_SUFFIXES)
        if not found:
            raise BagError(f'{self.path}: not a rosbag2 bag: no .mcap or .db3 storage file '
                           'in it (a bag directory holds metadata.yaml and its storage files)')
        return found

    def _open_files(self, files: list[Path], metadata: dict | None) -> None:
        """Each storage file on its own (single files, crash recovery)."""
        self._take_metadata(metadata)
        meta_topics = {}
        if metadata is not None:
            for topic in metadata.get('topics_with_message_count') or []:
                meta = topic.get('topic_metadata') or {}
                meta_topics[meta.get('name')] = meta
        if not self.relative_files:
            self.relative_files = [f.name for f in files]
        for path in files:
            source = self._open_file(path)
            self._sources.append(source)
            self.storage_id = self.storage_id or STORAGE_SUFFIXES.get(path.suffix, '')
            for conn in source.connections:
                info = self.topics.get(conn.topic)
                if info is None:
                    meta = meta_topics.get(conn.topic, {})
                    offered = conn.ext.offered_qos_profiles
                    if not offered and meta.get('offered_qos_profiles'):
                        offered = _parse_qos(meta['offered_qos_profiles'])
                    info = self.topics[conn.topic] = TopicInfo(
                        conn.topic, conn.msgtype, 0, conn.ext.serialization_format,
                        list(offered), meta.get('type_description_hash') or conn.digest or '',
                        conn.msgdef if conn.msgdef.format != MessageDefinitionFormat.NONE
                        else None)
                info.count += source.counts.get(conn.id, 0)
            if source.start_ns is not None:
                self.start_ns = min(self.start_ns or TIME_MAX, source.start_ns)
                self.end_ns = max(self.end_ns or 0, source.end_ns)
        self.message_count = sum(t.count for t in self.topics.values())

    def _open_file(self, path: Path) -> _Source:
        if path.suffix not in STORAGE_SUFFIXES:
            raise BagError(f'{path}: not a rosbag2 storage file (only .mcap and .db3 are read; '
                           'zstd-compressed files need their metadata.yaml)')
        try:
            reader = Reader(path)
            reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags' and sqlite's errors alike
            if path.suffix == '.mcap':
                return self._recover_mcap(path, exc)
            raise BagError(f'{path}: not a readable rosbag2 sqlite3 file ({_short(exc)}); '
                           'it may be damaged or not a bag at all') from None
        return _RosbagsSource.of_file(reader)

    def _recover_mcap(self, path: Path, exc: Exception) -> _Source:
        with open(path, 'rb') as f:
            head = f.read(len(MCAP_MAGIC))
        if head != MCAP_MAGIC:
            what = 'empty' if not head else 'not an MCAP file (wrong magic bytes)'
            raise BagError(f'{path}: {what}; it is damaged or not a bag file') from None
        problem = f'{path}: cut short or damaged (rosbags: {_short(exc)})'
        if self.strict:
            raise BagError(problem + '; a recording that crashed? Open it without strict to '
                           'read it up to its last complete chunk') from None
        source = _RecoveredMcap(path)
        if source.header_profile is None:
            raise BagError(f'{path}: cut short or damaged before its first complete record; '
                           'there is nothing to read') from None
        if source.header_profile != 'ros2':
            raise BagError(f'{path}: an MCAP file of profile {source.header_profile!r}, not '
                           'a ROS 2 bag') from None
        self._recovering(f'{problem}; read {sum(source.counts.values())} messages up to byte '
                         f'{source.good_bytes} of {source.size}'
                         + (f' ({source.stop_reason})' if source.stop_reason else ''))
        return source

    def _recovering(self, warning: str) -> None:
        self.complete = False
        self.warnings.append(warning)

    # -- topics and types -------------------------------------------------------------------------

    def _wanted(self, topics: Iterable[str] | None) -> list[str]:
        if topics is None:
            return list(self.topics)
        chosen = []
        for name in topics:
            name = name if name.startswith('/') else '/' + name
            if name not in self.topics:
                raise BagError(f'{self.path}: no topic {name} in the bag; it has '
                               + (', '.join(self.topics) or 'no topics'))
            chosen.append(name)
        return chosen

    def _build_typestore(self):
        store = interfaces.typestore()
        known = set(store.fielddefs)
        for info in self.topics.values():
            if info.type in known or info.definition is None:
                continue
            try:
                types = _types_from_definition(info.definition, info.type)
                store.register({k: v for k, v in types.items() if k not in known})
            except Exception as exc:  # noqa: BLE001 - a definition rosbags cannot parse
                self.warnings.append(f'{self.path}: the definition of {info.type} stored in the '
                                     f'bag does not parse ({_short(exc)})')
        return store

    def _unknown_type(self, msgtype: str, topic: str | None = None) -> str:
        where = f' (topic {topic})' if topic else ''
        return (f'{self.path}: unknown message type {msgtype}{where}: it is not installed '
                'here and the bag carries no definition of it; install its interface package '
                'or leave the topic out')


def _types_from_definition(definition: MessageDefinition, msgtype: str) -> dict:
    if definition.format == MessageDefinitionFormat.MSG:
        return get_types_from_msg(definition.data, msgtype)
    sep = '=' * 80 + '\n'
    types: dict = {}
    if definition.data.startswith(f'{sep}IDL: '):
        for part in definition.data.split(sep)[1:]:
            types.update(get_types_from_idl(part.split('\n', 1)[1]))
    else:
        types.update(get_types_from_idl(definition.data))
    return types


def _in_progress(metadata: dict) -> bool:
    custom = metadata.get('custom_data')
    return isinstance(custom, dict) and IN_PROGRESS_KEY in custom


def _parse_qos(value) -> list[Qos]:
    try:
        return parse_qos(value)
    except Exception:  # noqa: BLE001 - unreadable QoS: shown as none
        return []


def _short(exc: BaseException) -> str:
    text = str(exc).strip().rstrip('.') or type(exc).__name__
    return text.splitlines()[0]


# -- sources: where messages come from --------------------------------------------------------


class _Source:
    connections: list[Connection]
    counts: dict[int, int]
    start_ns: int | None
    end_ns: int | None

    def messages(self, topics: list[str], start_ns, stop_ns) -> Iterator[BagMessage]:
        raise NotImplementedError

    def close(self) -> None:
        pass


class _RosbagsSource(_Source):
    """A bag directory or a storage file, open in rosbags' Reader."""

    def __init__(self, reader: Reader, connections: list[Connection]) -> None:
        self.reader = reader
        self.connections = connections
        self.counts = {c.id: c.msgcount for c in connections}
        self.start_ns = self.end_ns = None

    @classmethod
    def of_file(cls, reader: Reader) -> _RosbagsSource:
        source = cls(reader, list(reader.connections))
        if reader.message_count:
            # rosbags' end_time is one past the last message
            source.start_ns, source.end_ns = reader.start_time, reader.end_time - 1
        return source

    def messages(self, topics, start_ns, stop_ns):
        chosen = [c for c in self.connections if c.topic in topics]
        if not chosen:            # rosbags reads every connection when given none
            return
        try:
            for conn, stamp, data in self.reader.messages(chosen, start_ns, stop_ns):
                yield BagMessage(conn.topic, conn.msgtype, stamp, data)
        except Exception as exc:  # noqa: BLE001 - damaged chunks, sqlite errors, ...
            raise BagError(f'{self.reader.path}: damaged: {_short(exc)}; the messages before '
                           'this point were read') from None

    def close(self) -> None:
        if self.reader.is_open:
            self.reader.close()


class _RecoveredMcap(_Source):
    """An mcap file without a usable summary or footer, read sequentially up to where it
    stops making sense (the end of the last complete chunk, or a damaged record)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.size = path.stat().st_size
        self.header_profile: str | None = None
        self.stop_reason = ''
        self.good_bytes = 0
        self.connections = []
        self.counts: dict[int, int] = {}
        self.start_ns = self.end_ns = None
        self._schemas: dict[int, object] = {}
        self._channels: dict[int, Connection] = {}
        for message in self._scan(collect=True):
            self.counts[message.channel_id] = self.counts.get(message.channel_id, 0) + 1
            stamp = message.log_time
            self.start_ns = stamp if self.start_ns is None else min(self.start_ns, stamp)
            self.end_ns = stamp if self.end_ns is None else max(self.end_ns, stamp)

    def _scan(self, collect: bool):
        """Messages record by record, a chunk's sorted by time; schemas and channels taken on
        the way (``collect``)."""
        from mcap.exceptions import EndOfFile, McapError
        from mcap.records import Channel, Chunk, Header, Message, Schema
        from mcap.stream_reader import StreamReader, breakup_chunk

        with open(self.path, 'rb') as f:
            stream = StreamReader(f, emit_chunks=True, record_size_limit=1 << 32)
            records = stream.records
            while True:
                try:
                    record = next(records)
                    inner = (breakup_chunk(record, validate_crc=True)
                             if isinstance(record, Chunk) else [record])
                except StopIteration:
                    break
                except (EndOfFile, struct.error) as exc:
                    if collect:
                        self.stop_reason = ('it ends without the summary and footer a closed '
                                            'file has' if f.tell() >= self.size and
                                            self.good_bytes == self.size else
                                            f'cut inside a record ({_short(exc)})')
                    break
                except (McapError, ValueError, OSError, MemoryError) as exc:
                    if collect:
                        self.stop_reason = f'damaged record: {_short(exc)}'
                    break
                except Exception as exc:  # noqa: BLE001 - damaged bytes fail in odd ways
                    if collect:
                        self.stop_reason = f'damaged record: {_short(exc)}'
                    break
                if collect:
                    self.good_bytes = f.tell()
                batch = []
                for item in inner:
                    if isinstance(item, Message):
                        batch.append(item)
                    elif collect and isinstance(item, Schema):
                        self._schemas[item.id] = item
                    elif collect and isinstance(item, Channel):
                        self._add_channel(item)
                    elif collect and isinstance(item, Header):
                        self.header_profile = item.profile
                batch.sort(key=lambda m: m.log_time)
                yield from batch

    def _add_channel(self, channel) -> None:
        from rosbags.interfaces import ConnectionExtRosbag2
        if channel.id in self._channels:
            return
        schema = self._schemas.get(channel.schema_id)
        msgtype = schema.name if schema is not None else ''
        msgdef = MessageDefinition(MessageDefinitionFormat.NONE, '')
        if schema is not None and schema.encoding in ('ros2msg', 'ros2idl', 'omgidl'):
            fmt = (MessageDefinitionFormat.MSG if schema.encoding == 'ros2msg'
                   else MessageDefinitionFormat.IDL)
            msgdef = MessageDefinition(fmt, schema.data.decode(errors='replace'))
        offered = _parse_qos(channel.metadata.get('offered_qos_profiles', ''))
        conn = Connection(channel.id, channel.topic, msgtype, msgdef,
                          channel.metadata.get('topic_type_hash', ''), 0,
                          ConnectionExtRosbag2(channel.message_encoding, offered), self)
        self._channels[channel.id] = conn
        self.connections.append(conn)

    def messages(self, topics, start_ns, stop_ns):
        wanted = {c.id: c for c in self.connections if c.topic in topics}
        if not wanted:
            return
        lo = start_ns if start_ns is not None else -1
        hi = stop_ns if stop_ns is not None else TIME_MAX + 1
        for message in self._scan(collect=False):
            conn = wanted.get(message.channel_id)
            if conn is not None and lo <= message.log_time < hi:
                yield BagMessage(conn.topic, conn.msgtype, message.log_time, message.data)
