"""rosbag2 bags on the ``rosbags`` library (pure, no rclpy): type definitions, write, open, info.

Bags are rosbag2's own on-disk format (version 9: ``metadata.yaml`` plus one ``.mcap`` or
``.db3`` file), so they move between tt and a full ROS 2 install. Message definitions are
stored with every topic: standard types from rosbags' Jazzy typestore, others (tt_msgs) from
the ``.msg`` files their packages install under ``<prefix>/share/<pkg>/msg/``.
"""

import datetime
import os

from rosbags.interfaces import Nodetype
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
import yaml

from tt_ros.errors import one_line_reason
from tt_ros.index import interface_file
from tt_ros.messages import seconds_text

STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}


class BagError(Exception):
    """A bag that cannot be written or read (one-line message)."""


def _msg_file(msgtype, ament_prefix_path=None):
    """The installed ``.msg`` file of ``pkg/msg/Type``, or None."""
    pkg, _, name = msgtype.split('/')
    path = interface_file(pkg, 'msg', name, ament_prefix_path)
    return path if path and os.path.isfile(path) else None


def _referenced_types(fields):
    """Names of the message types used by the fields of a rosbags field definition."""
    for _name, (kind, detail) in fields:
        if kind == Nodetype.NAME:
            yield detail
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE) and detail[0][0] == Nodetype.NAME:
            yield detail[0][1]


class TypeRegistry:
    """A rosbags typestore that learns the types it is asked about.

    Starts from rosbags' ROS 2 Jazzy store; a type it lacks (and, recursively, the types that
    one uses) is read from the installed ``.msg`` file found through ``AMENT_PREFIX_PATH``.
    """

    def __init__(self, ament_prefix_path=None):
        self.store = get_typestore(Stores.ROS2_JAZZY)
        self.ament_prefix_path = ament_prefix_path

    def ensure(self, msgtype):
        """Make ``msgtype`` ('pkg/msg/Type') known; BagError when no definition is found."""
        todo = [msgtype]
        while todo:
            name = todo.pop()
            if name in self.store.fielddefs:
                continue
            path = _msg_file(name, self.ament_prefix_path)
            if path is None:
                raise BagError(f"no message definition found for '{name}' (no .msg installed)")
            with open(path, encoding='utf-8') as f:
                types = get_types_from_msg(f.read(), name)
            self.store.register(types)
            todo.extend(_referenced_types(types[name][1]))

    def definition(self, msgtype):
        """(msgdef text as rosbag2 stores it, RIHS01 type hash) of ``msgtype``."""
        self.ensure(msgtype)
        msgdef, _ = self.store.generate_msgdef(msgtype, ros_version=2)
        return msgdef, self.store.hash_rihs01(msgtype)


def default_bag_name(now=None):
    """``rosbag2_YYYY_MM_DD-HH_MM_SS``, the name rosbag2 gives a bag without ``-o``."""
    now = now or datetime.datetime.now()
    return now.strftime('rosbag2_%Y_%m_%d-%H_%M_%S')


class BagWriter:
    """A rosbag2 bag being written: ``add_topic`` once per topic, ``write`` bytes, ``close``."""

    def __init__(self, path, storage='mcap', registry=None):
        if storage not in STORAGES:
            raise BagError(f"unknown storage '{storage}' (use mcap or sqlite3)")
        if os.path.exists(path):
            raise BagError(f"output '{path}' already exists")
        self.registry = registry or TypeRegistry()
        self.writer = Writer(path, version=Writer.VERSION_LATEST, storage_plugin=STORAGES[storage])
        self.writer.open()
        self.count = 0

    def add_topic(self, topic, msgtype, offered_qos=(), type_hash=None):
        """Register a topic; returns the connection to pass to ``write``.

        ``offered_qos``: rosbags ``Qos`` of each publisher (stored in metadata.yaml);
        ``type_hash``: the RIHS01 hash seen in the graph (default: computed from the msgdef).
        """
        msgdef, rihs01 = self.registry.definition(msgtype)
        return self.writer.add_connection(topic, msgtype, msgdef=msgdef,
                                          rihs01=type_hash or rihs01,
                                          offered_qos_profiles=list(offered_qos))

    def write(self, connection, timestamp_ns, data):
        """Append one serialised (CDR) message received at ``timestamp_ns`` (ns since epoch)."""
        self.writer.write(connection, timestamp_ns, data)
        self.count += 1

    def close(self):
        """Write the index and metadata.yaml; the bag is complete after this."""
        if self.writer.storage is not None:
            self.writer.close()


def bag_folder(path):
    """The bag directory ``path`` names: itself, or the folder of a storage file (.mcap,
    .db3) given in its place when that folder is a bag (has metadata.yaml), as rosbag2 takes
    either."""
    folder = os.path.dirname(path) or '.'
    if (os.path.isfile(path) and path.endswith(('.mcap', '.db3'))
            and os.path.isfile(os.path.join(folder, 'metadata.yaml'))):
        return folder
    return path


def incomplete_reason(folder):
    """'incomplete: NAME.mcap without metadata.yaml (...killed?)' for a bag directory whose
    recording never ended (a storage file, no metadata.yaml), else ''."""
    if not os.path.isdir(folder) or os.path.isfile(os.path.join(folder, 'metadata.yaml')):
        return ''
    storage = sorted(f for f in os.listdir(folder) if f.endswith(('.mcap', '.db3')))
    return (f'incomplete: {storage[0]} without metadata.yaml (a recording that did not end: '
            'killed?)' if storage else '')


def bag_problem(path):
    """Why ``path`` is no rosbag2 bag a reader can open, one line, or '' (a directory with
    metadata.yaml, or a .mcap or .db3 file, whose contents the reader then checks). Said
    before rosbags is asked: it said "Expected metadata file '<the folder>' does not exist"
    of an empty folder and "Unrecognized storage format ''" of an empty file."""
    if not os.path.exists(path):
        return 'no such file or folder'
    if os.path.isdir(path):
        if os.path.isfile(os.path.join(path, 'metadata.yaml')):
            return ''
        return incomplete_reason(path) or 'no metadata.yaml in it'
    if str(path).endswith(('.mcap', '.db3')):
        return ''
    return 'expected a directory with metadata.yaml, or a .mcap or .db3 file'


def open_bag(path):
    """An open rosbags Reader for the bag directory ``path`` (or a storage file in it:
    :func:`bag_folder`); BagError with a one-line reason.

    Checks that the storage files are complete: every message the metadata counts is read
    back (a cut .mcap or .db3 fails here, not half-way through a replay).
    """
    path = bag_folder(path)
    if not os.path.exists(path):
        raise BagError(f"bag '{path}' does not exist")
    if not os.path.isdir(path):
        raise BagError(f"'{path}' is not a rosbag2 bag (expected a directory with metadata.yaml, "
                       'or a .mcap or .db3 file in one)')
    if not os.path.isfile(os.path.join(path, 'metadata.yaml')):
        killed = incomplete_reason(path)
        raise BagError(f"bag '{path}' is {killed}" if killed
                       else f"'{path}' is not a rosbag2 bag: no metadata.yaml in it")
    reader = Reader(path)
    try:
        reader.open()
        counted = sum(1 for _ in reader.messages())
    except Exception as exc:  # rosbags raises several types for corrupt files
        try:
            reader.close()
        except Exception:
            pass
        raise BagError(f"bag '{path}' is truncated or corrupt: {one_line_reason(exc)}") from None
    if counted != reader.message_count:
        reader.close()
        raise BagError(f"bag '{path}' is truncated or corrupt: metadata counts "
                       f'{reader.message_count} messages, storage holds {counted}')
    return reader


def _stamp(ns):
    t = datetime.datetime.fromtimestamp(ns / 1e9)
    return f'{t:%b %d %Y %H:%M:%S}.{ns % 1_000_000_000:09d} ({seconds_text(ns)})'


def _size(nbytes):
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if nbytes < 1024 or unit == 'GiB':
            return f'{nbytes:.1f} {unit}' if unit != 'B' else f'{nbytes} B'
        nbytes /= 1024
    return None


def format_info(reader, path):
    """The summary ``ros2 bag info`` prints, for the bag at ``path`` opened as ``reader``."""
    with open(os.path.join(path, 'metadata.yaml'), encoding='utf-8') as f:
        meta = yaml.safe_load(f)['rosbag2_bagfile_information']
    files = [os.path.basename(p) for p in meta['relative_file_paths']]
    size = sum(os.path.getsize(os.path.join(path, p)) for p in files)
    label = 'Topic information: '
    topics = [
        f'Topic: {c.topic} | Type: {c.msgtype} | Count: {c.msgcount} | '
        f'Serialization Format: {c.ext.serialization_format}'
        for c in sorted(reader.connections, key=lambda c: c.topic)
    ]
    empty = reader.message_count == 0
    start = meta['starting_time']['nanoseconds_since_epoch']
    duration = 0 if empty else meta['duration']['nanoseconds']
    lines = [
        f'Files:             {", ".join(files)}',
        f'Bag size:          {_size(size)}',
        f'Storage id:        {meta["storage_identifier"]}',
        f'ROS Distro:        {meta.get("ros_distro", "")}',
        f'Duration:          {duration / 1e9:.9f}s',
        f'Start:             {"-" if empty else _stamp(start)}',
        f'End:               {"-" if empty else _stamp(start + duration)}',
        f'Messages:          {reader.message_count}',
        label + ('\n' + ' ' * len(label)).join(topics),
    ]
    return '\n'.join(lines)
