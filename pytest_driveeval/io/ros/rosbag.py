"""ROS 2 bags (sqlite3 / mcap) without ROS, on top of ``rosbags``.

Messages are streamed one at a time straight from the storage cursor, so
memory stays flat however long the bag is: a decoded point cloud is a view
over its own serialized message and is released with it.  From sqlite3
storage each message is copied once, from the OS page cache into its own
buffer (``bag_sqlite``), and a PointCloud2's header and
layout are read from its CDR bytes directly (``pointcloud2_cdr``).

Every failure surfaces as :class:`BagError` naming the bag path and, where it
applies, the topic and message index.  What is opened, and the checks before
(no metadata.yaml, ROS 1, MCAP chunks against their index), are in
``bag_files``.  A topic that yields fewer messages than the bag lists is an
error too, not a shorter evaluation.
"""
from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from .bag_files import BagError, storage_files, storage_for
from .bag_sqlite import read_into_buffers
from .pointcloud2 import PointCloud2Error, decode_pointcloud2
from .pointcloud2_cdr import read_pointcloud2_cdr, standard_layout
from .tf import TFBuffer, TransformError

if TYPE_CHECKING:
    from typing_extensions import Self  # typing.Self needs Python 3.11

__all__ = [
    "Bag",
    "BagError",
    "BagWriter",
    "DiagnosticRecord",
    "DiagnosticsLog",
    "PointCloudFrame",
    "default_typestore",
    "diagnostic_array",
    "iter_pointclouds",
    "read_diagnostics",
    "read_tf",
    "tf_message",
]

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
TFMESSAGE = "tf2_msgs/msg/TFMessage"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
_DIAG_TOPICS = ("/diagnostics", "/diagnostics_agg")


_TYPESTORE = None


def default_typestore():
    """The ROS 2 Humble typestore (Autoware's distro), built once."""
    global _TYPESTORE
    if _TYPESTORE is None:
        from rosbags.typesys import Stores, get_typestore
        _TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)
    return _TYPESTORE


def _stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _secs(ns: int | None) -> str:
    """A stamp as seconds.nanoseconds, exact (a float would round the nanoseconds)."""
    if ns is None:
        return "?"
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return f"{sec}.{nsec:09d}"


def _sqlite_hint(exc: Exception) -> str:
    # SQLite cannot say which pages a cut or overwritten .db3 lost; its own tool salvages the rest.
    if "malformed" in str(exc) or "not a database" in str(exc):
        return ("; the .db3 file is damaged (bytes missing or overwritten): `sqlite3 <file>.db3 .recover | "
                "sqlite3 <recovered>.db3` salvages the rows that are left, and with the bag's metadata.yaml "
                "beside it the missing messages are then counted")
    return ""


class PointCloudFrame(NamedTuple):
    stamp_ns: int       # header.stamp, not the bag's receive time
    frame_id: str
    points: np.ndarray  # structured, a view over the message's data


class Bag:
    """An open ROS 2 bag directory (metadata.yaml + .db3/.mcap) or single storage file."""

    def __init__(self, path: str | os.PathLike, typestore=None):
        from rosbags.rosbag2 import Reader

        self.path = Path(path)
        self.typestore = typestore or default_typestore()
        self._registered: set[str] = set()
        storage = storage_for(self.path)
        self._has_metadata = storage.is_dir()
        try:
            self._reader = Reader(storage)
            self._reader.open()
            read_into_buffers(self._reader)
        except Exception as exc:  # rosbags/apsw/yaml all raise their own types
            raise BagError(f"{self.path}: cannot open bag ({storage_files(self.path)}): "
                           f"{type(exc).__name__}: {exc}{_sqlite_hint(exc)}") from exc

    # -- context management ------------------------------------------------
    def close(self) -> None:
        if self._reader.is_open:
            self._reader.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- metadata ----------------------------------------------------------
    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> message type."""
        return {c.topic: c.msgtype for c in self._reader.connections}

    def message_count(self, topic: str) -> int:
        return sum(c.msgcount for c in self._connections(topic))

    @property
    def start_time_ns(self) -> int:
        return self._reader.start_time

    @property
    def end_time_ns(self) -> int:
        return self._reader.end_time

    def _connections(self, topic: str, msgtype: str | None = None) -> list:
        conns = [c for c in self._reader.connections if c.topic == topic]
        if not conns:
            listing = ", ".join(f"{t} [{m}]" for t, m in sorted(self.topics.items()))
            raise BagError(f"{self.path}: topic {topic!r} not in bag; available: {listing or 'none'}")
        if msgtype is not None:
            wrong = {c.msgtype for c in conns} - {msgtype}
            if wrong:
                raise BagError(f"{self.path}: topic {topic!r} has type {sorted(wrong)}, "
                               f"expected {msgtype}")
        for c in conns:
            self._ensure_type(c)
        return conns

    def _ensure_type(self, conn) -> None:
        """Register a message type the typestore lacks from the bag's own definition."""
        if conn.msgtype in self.typestore.types or conn.msgtype in self._registered:
            return
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.typesys import get_types_from_idl, get_types_from_msg

        msgdef = getattr(conn, "msgdef", None)
        try:
            if msgdef is None or msgdef.format == MessageDefinitionFormat.NONE or not msgdef.data:
                raise ValueError("bag carries no message definition")
            if msgdef.format == MessageDefinitionFormat.IDL:
                types = get_types_from_idl(msgdef.data)
            else:
                types = get_types_from_msg(msgdef.data, conn.msgtype)
            self.typestore.register(types)
        except Exception as exc:
            raise BagError(f"{self.path}: topic {conn.topic!r}: unknown message type "
                           f"{conn.msgtype!r} ({exc})") from exc
        self._registered.add(conn.msgtype)

    # -- reading -----------------------------------------------------------
    def raw_messages(self, topic: str, msgtype: str | None = None,
                     start_ns: int | None = None, stop_ns: int | None = None
                     ) -> Iterator[tuple[int, Any, int, bytes]]:
        """(index, connection, log_time_ns, serialized message), streamed in log-time order.

        The message is ``bytes``, or for sqlite3 storage a read-only memoryview over a
        buffer of its own (``bag_sqlite``): either can be kept, and compares by value.

        Reading the whole topic, fewer messages than the bag lists is a BagError:
        rows deleted from a .db3, or a chunk lost from a file, would otherwise
        just make a shorter evaluation."""
        conns = self._connections(topic, msgtype)
        expected = sum(c.msgcount for c in conns)
        index, first_ns, log_ns, gap = -1, None, None, (-1, -1, 0, 0)  # gap: length, index before, log times
        it = self._reader.messages(conns, start=start_ns, stop=stop_ns)
        while True:
            last_ns = log_ns
            try:
                conn, log_ns, raw = next(it)
            except StopIteration:
                if start_ns is None and stop_ns is None and index + 1 < expected:
                    raise BagError(self._shortfall(topic, index + 1, expected, first_ns, last_ns, gap)) from None
                return
            except Exception as exc:
                after = f"message #{index} (log time {_secs(last_ns)})" if index >= 0 else "its first message"
                raise BagError(f"{self.path}: topic {topic!r}: corrupt or truncated bag after {after} "
                               f"({storage_files(self.path)}): {type(exc).__name__}: {exc}{_sqlite_hint(exc)}"
                               ) from exc
            index += 1
            if last_ns is None:
                first_ns = log_ns
            elif log_ns - last_ns > gap[0]:
                gap = (log_ns - last_ns, index - 1, last_ns, log_ns)
            yield index, conn, log_ns, raw

    def _shortfall(self, topic: str, found: int, expected: int, first_ns, last_ns, gap: tuple) -> str:
        source = "metadata.yaml" if self._has_metadata else "the storage file's own index"
        text = (f"{self.path}: topic {topic!r}: {source} lists {expected} messages, but only {found} can "
                f"be read ({storage_files(self.path)}): {expected - found} are missing (deleted, or lost with "
                f"a damaged part of the file)")
        if not found:
            return text
        # Where they went missing: the longest stretch without a message, the bag's ends included.
        begin, end = self.start_time_ns, self.end_time_ns - 1
        head, tail = first_ns - begin, end - last_ns
        if tail >= max(head, gap[0]):
            return text + (f"; the messages stop at #{found - 1} (log time {_secs(last_ns)}), "
                           f"{tail / 1e9:.3f} s before the bag ends (log time {_secs(end)})")
        if head >= gap[0]:
            return text + (f"; the messages start at log time {_secs(first_ns)}, {head / 1e9:.3f} s after the "
                           f"bag begins (log time {_secs(begin)})")
        return text + (f"; the longest gap, {gap[0] / 1e9:.3f} s, is between message #{gap[1]} (log time "
                       f"{_secs(gap[2])}) and #{gap[1] + 1} (log time {_secs(gap[3])})")

    def messages(self, topic: str, msgtype: str | None = None, **window) -> Iterator[tuple[int, Any]]:
        """(log_time_ns, deserialized message) for each message of ``topic``."""
        for index, conn, log_ns, raw in self.raw_messages(topic, msgtype, **window):
            yield log_ns, self._deserialize(raw, conn, index)

    def _deserialize(self, raw, conn, index: int):
        try:
            return self.typestore.deserialize_cdr(raw, conn.msgtype)
        except Exception as exc:
            raise BagError(f"{self.path}: topic {conn.topic!r} message #{index}: cannot decode "
                           f"{conn.msgtype}: {type(exc).__name__}: {exc}") from exc

    def pointclouds(self, topic: str, **window) -> Iterator[PointCloudFrame]:
        """Stream PointCloud2 frames; each ``points`` array views its own message buffer.

        A topic without a single message is a BagError: there is nothing to evaluate."""
        count = 0
        plain = standard_layout(self.typestore, default_typestore())
        longest = getattr(self.typestore, "max_sequence_length", 2**32 - 1)
        for index, conn, _, raw in self.raw_messages(topic, POINTCLOUD2, **window):
            msg = read_pointcloud2_cdr(raw, longest) if plain else None
            if msg is not None:
                stamp_ns, frame_id = msg.sec * 1_000_000_000 + msg.nanosec, msg.frame_id
            else:  # big-endian CDR, or something rosbags will name
                msg = self._deserialize(raw, conn, index)
                stamp_ns, frame_id = _stamp_ns(msg.header.stamp), msg.header.frame_id
            where = f"{self.path}: {topic} message #{index} (stamp {_secs(stamp_ns)}, frame {frame_id!r})"
            try:
                points = decode_pointcloud2(msg, where=where)
            except PointCloud2Error as exc:
                raise BagError(str(exc)) from exc
            count += 1
            yield PointCloudFrame(stamp_ns, frame_id, points)
        if not count:
            raise BagError(self._no_messages(topic, window))

    def _no_messages(self, topic: str, window: dict) -> str:
        start, stop = window.get("start_ns"), window.get("stop_ns")
        when = "" if start is None and stop is None else \
            f" with log time in [{_secs(start) if start is not None else '-inf'}, " \
            f"{_secs(stop) if stop is not None else 'inf'})"
        counts = ", ".join(f"{c.topic} [{c.msgtype}] x{c.msgcount}"
                           for c in sorted(self._reader.connections, key=lambda c: c.topic))
        return f"{self.path}: topic {topic!r} has no messages{when}; the bag holds: {counts}"

    def read_tf(self, topics: Iterable[str] = ("/tf", "/tf_static"),
                buffer: TFBuffer | None = None) -> TFBuffer:
        """Fill a TFBuffer from TFMessage topics; absent topics are skipped, none present is an error."""
        buffer = buffer if buffer is not None else TFBuffer()
        present = [t for t in topics if t in self.topics]
        if not present:
            self._connections(next(iter(topics), "/tf"))  # raises with the topic listing
        for topic in present:
            static = topic.endswith("_static")
            for log_ns, msg in self.messages(topic, TFMESSAGE):
                try:
                    buffer.add_tf_message(msg, static=static)
                except TransformError as exc:
                    raise BagError(f"{self.path}: topic {topic!r} at log time {log_ns}: {exc}") from exc
        return buffer

    def read_diagnostics(self, topic: str | None = None) -> DiagnosticsLog:
        """All DiagnosticStatus entries of /diagnostics (or /diagnostics_agg, or ``topic``)."""
        if topic is None:
            topic = next((t for t in _DIAG_TOPICS if t in self.topics), _DIAG_TOPICS[0])
        stamps, names, levels, texts, hw, values = [], [], [], [], [], []
        for log_ns, msg in self.messages(topic, DIAGNOSTIC_ARRAY):
            stamp = _stamp_ns(msg.header.stamp) or log_ns  # unstamped arrays are common
            for st in msg.status:
                stamps.append(stamp)
                names.append(st.name)
                levels.append(int.from_bytes(st.level, "little") if isinstance(st.level, bytes)
                              else int(st.level))
                texts.append(st.message)
                hw.append(st.hardware_id)
                values.append({kv.key: kv.value for kv in st.values})
        return DiagnosticsLog.from_lists(stamps, names, levels, texts, hw, values)


class DiagnosticRecord(NamedTuple):
    stamp_ns: int
    name: str
    level: int  # 0 OK, 1 WARN, 2 ERROR, 3 STALE
    message: str
    hardware_id: str = ""
    values: dict | None = None


@dataclass
class DiagnosticsLog:
    """Diagnostic statuses as time-sorted columns."""

    stamps_ns: np.ndarray
    names: np.ndarray
    levels: np.ndarray
    messages: np.ndarray
    hardware_ids: np.ndarray
    values: list

    OK, WARN, ERROR, STALE = 0, 1, 2, 3

    @classmethod
    def from_lists(cls, stamps, names, levels, messages, hardware_ids=None, values=None):
        n = len(stamps)
        order = np.argsort(np.asarray(stamps, dtype=np.int64), kind="stable")
        obj = lambda xs: np.asarray(xs, dtype=object).reshape(n)[order]
        return cls(np.asarray(stamps, dtype=np.int64)[order], obj(names),
                   np.asarray(levels, dtype=np.int16).reshape(n)[order], obj(messages),
                   obj(hardware_ids if hardware_ids is not None else [""] * n),
                   [(values or [None] * n)[i] for i in order])

    def __len__(self) -> int:
        return self.stamps_ns.size

    def record(self, i: int) -> DiagnosticRecord:
        return DiagnosticRecord(int(self.stamps_ns[i]), self.names[i], int(self.levels[i]),
                                self.messages[i], self.hardware_ids[i], self.values[i])

    def status_names(self) -> list[str]:
        return sorted(set(self.names.tolist()))

    def select(self, name: str) -> DiagnosticsLog:
        m = self.names == name
        return DiagnosticsLog(self.stamps_ns[m], self.names[m], self.levels[m], self.messages[m],
                              self.hardware_ids[m], [v for v, k in zip(self.values, m) if k])

    def levels_at(self, name: str, stamps_ns, max_age_ns: int | None = None) -> np.ndarray:
        """Level of status ``name`` in force at each stamp (latest at or before); -1 if none."""
        sub = self.select(name)
        q = np.atleast_1d(np.asarray(stamps_ns, dtype=np.int64))
        idx = np.searchsorted(sub.stamps_ns, q, side="right") - 1
        out = np.where(idx >= 0, sub.levels[np.clip(idx, 0, None)] if len(sub) else -1, -1)
        if max_age_ns is not None and len(sub):
            stale = q - sub.stamps_ns[np.clip(idx, 0, None)] > max_age_ns
            out = np.where(stale, -1, out)
        return out.astype(np.int16)

    def status_at(self, name: str, stamp_ns: int, max_age_ns: int | None = None
                  ) -> DiagnosticRecord | None:
        """The status ``name`` in force at ``stamp_ns`` (latest at or before), or None."""
        sub = self.select(name)
        i = int(np.searchsorted(sub.stamps_ns, stamp_ns, side="right")) - 1
        if i < 0 or (max_age_ns is not None and stamp_ns - sub.stamps_ns[i] > max_age_ns):
            return None
        return sub.record(i)


# -- module-level conveniences ---------------------------------------------
def iter_pointclouds(path, topic: str, typestore=None, **window) -> Iterator[PointCloudFrame]:
    """Open a bag and stream one PointCloud2 topic (bag closed when exhausted/closed)."""
    with Bag(path, typestore) as bag:
        yield from bag.pointclouds(topic, **window)


def read_tf(path, topics=("/tf", "/tf_static"), typestore=None) -> TFBuffer:
    with Bag(path, typestore) as bag:
        return bag.read_tf(topics)


def read_diagnostics(path, topic: str | None = None, typestore=None) -> DiagnosticsLog:
    with Bag(path, typestore) as bag:
        return bag.read_diagnostics(topic)


# -- writing ---------------------------------------------------------------
class BagWriter:
    """Create a bag (sqlite3 or mcap) for tests and demos.

    ``write(topic, msg)`` registers the topic on first use with the message's
    own type; the log time defaults to the header stamp.
    """

    def __init__(self, path, storage: str = "sqlite3", typestore=None, version: int = 8):
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugins = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
        if storage not in plugins:
            raise ValueError(f"storage must be one of {sorted(plugins)}, got {storage!r}")
        self.path = Path(path)
        self.typestore = typestore or default_typestore()
        self._writer = Writer(self.path, version=version, storage_plugin=plugins[storage])
        self._conns: dict[str, Any] = {}
        self._writer.open()

    def write(self, topic: str, msg, log_time_ns: int | None = None) -> None:
        msgtype = msg.__msgtype__
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._conns[topic] = self._writer.add_connection(topic, msgtype,
                                                                    typestore=self.typestore)
        elif conn.msgtype != msgtype:
            raise BagError(f"{self.path}: topic {topic!r} is {conn.msgtype}, got {msgtype}")
        if log_time_ns is None:
            header = getattr(msg, "header", None)
            if header is None and getattr(msg, "transforms", None):
                header = msg.transforms[0].header  # TFMessage: stamp of its first transform
            if header is None:
                raise ValueError(f"{topic}: {msgtype} has no header; pass log_time_ns")
            log_time_ns = _stamp_ns(header.stamp)
        self._writer.write(conn, int(log_time_ns), self.typestore.serialize_cdr(msg, msgtype))

    def close(self) -> None:
        self._writer.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _time(typestore, stamp_ns: int):
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return typestore.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def tf_message(transforms: Iterable[tuple], typestore=None):
    """TFMessage from (parent, child, stamp_ns, (x, y, z), (qx, qy, qz, qw)) tuples."""
    ts = typestore or default_typestore()
    T = ts.types
    out = []
    for parent, child, stamp_ns, t, q in transforms:
        out.append(T["geometry_msgs/msg/TransformStamped"](
            header=T["std_msgs/msg/Header"](stamp=_time(ts, stamp_ns), frame_id=parent),
            child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=float(t[0]), y=float(t[1]), z=float(t[2])),
                rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]),
                                                           z=float(q[2]), w=float(q[3])))))
    return T[TFMESSAGE](transforms=out)


def diagnostic_array(stamp_ns: int, statuses: Iterable[tuple], typestore=None):
    """DiagnosticArray from (name, level, message[, values dict[, hardware_id]]) tuples."""
    ts = typestore or default_typestore()
    T = ts.types
    out = []
    for st in statuses:
        name, level, message = st[:3]
        values = st[3] if len(st) > 3 else {}
        hw = st[4] if len(st) > 4 else ""
        out.append(T["diagnostic_msgs/msg/DiagnosticStatus"](
            level=int(level), name=name, message=message, hardware_id=hw,
            values=[T["diagnostic_msgs/msg/KeyValue"](key=k, value=str(v))
                    for k, v in values.items()]))
    return T[DIAGNOSTIC_ARRAY](
        header=T["std_msgs/msg/Header"](stamp=_time(ts, stamp_ns), frame_id=""), status=out)
