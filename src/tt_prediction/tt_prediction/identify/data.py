"""Loading measured ball tracks: trajectory folders (CSV) and rosbag2 bags.

A *track* is one measured ball: sample times ``t`` (s, sorted), positions ``p`` (n, 3) in the
table frame (m), the measured initial spin (rad/s) or None, and a label. Spin counts as
measured only where index.csv says so (column ``spin_source``: ``measured``, the default
where spin is given, or ``estimated``); a bag's BallState spin is perception's estimate and
never counts as measured. Loading checks the
format and raises :class:`DataError` with a one-line message naming the file; cleaning
(sorting, duplicate stamps, non-finite rows) is explicit and counted in ``Track.notes``.
"""

import csv
import dataclasses
import math
import os
import pathlib

import numpy as np
from tt_ros.errors import one_line_reason

from ..predict import MAX_SPIN
from ..units import outside_room, position_error, sample_time_error, time_error


class DataError(ValueError):
    """Bad input: the message names the file and what is wrong."""


@dataclasses.dataclass
class Track:
    """One measured ball track (table frame, SI units)."""

    name: str
    t: np.ndarray
    """Sample times, s, strictly increasing."""
    p: np.ndarray
    """Measured ball-centre positions (n, 3), m."""
    spin: np.ndarray = None
    """Measured spin at t[0], rad/s (3,), or None when not measured (an estimate of the
    spin, e.g. by perception, is never put here: see ``spin_source``)."""
    label: str = ''
    notes: dict = dataclasses.field(default_factory=dict)
    """Counts of what cleaning and segmentation dropped, by reason."""
    spin_source: str = ''
    """Where the track's spin came from: 'measured' (then ``spin`` holds it), 'estimated'
    (by perception or a filter: not used as a measurement) or '' (none given)."""


LOADER_REMOVED = ('outside_room_rows', 'non_finite_rows', 'duplicate_stamps_merged')
"""The notes of :func:`clean_samples` that count rows it removed (``unsorted_rows`` counts
rows it kept, sorted)."""


def clean_samples(name, t, p):
    """Drop rows outside the room (a few wild samples; most of them: DataError, a file in
    millimetres) and non-finite rows, sort by time, merge duplicate stamps (mean position).

    Returns ``(t, p, notes)`` with the number of rows affected by each step.
    """
    notes = {}
    reason = position_error(p, 'x, y, z', most=True)
    if reason:
        raise DataError(f'{name}: {reason}')
    wild = outside_room(p)
    if wild.any():              # a sample tens of metres off: a false match, not the ball
        notes['outside_room_rows'] = int(wild.sum())
        t, p = t[~wild], p[~wild]
    finite = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
    if not finite.all():
        notes['non_finite_rows'] = int((~finite).sum())
        t, p = t[finite], p[finite]
    order = np.argsort(t, kind='stable')
    if np.any(order != np.arange(len(t))):
        notes['unsorted_rows'] = int(np.sum(order != np.arange(len(t))))
        t, p = t[order], p[order]
    unique, inverse, counts = np.unique(t, return_inverse=True, return_counts=True)
    if len(unique) < len(t):
        notes['duplicate_stamps_merged'] = int(len(t) - len(unique))
        merged = np.zeros((len(unique), 3))
        np.add.at(merged, inverse, p)
        p = merged / counts[:, None]
        t = unique
    return t, p, notes


def _read_csv(path):
    """Rows of a CSV file as (header, list of rows, the file line of each row), blank lines
    left out; DataError when unreadable. (Lines were counted from the rows: after a blank
    line, an error named the line before its own; a walk-through, 6 Dec 2026.)"""
    try:
        # utf-8-sig: a byte-order mark, as spreadsheet programs write, is not a header's.
        with open(path, newline='', encoding='utf-8-sig') as f:
            reader = csv.reader(f)
            numbered = [(reader.line_num, r) for r in reader if r and any(c.strip() for c in r)]
    except OSError as exc:
        raise DataError(f'{path}: cannot read: {exc.strerror}') from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DataError(f'{path}: not a text CSV file: {exc}') from None
    if not numbered:
        raise DataError(f'{path}: empty file')
    lines, rows = zip(*numbered, strict=True)
    header = [c.strip() for c in rows[0]]
    for row, line in zip(rows[1:], lines[1:], strict=True):
        if len(row) > len(header) and any(c.strip() for c in row[len(header):]):
            raise DataError(f'{path}: line {line} has {len(row)} cells, the header '
                            f'{len(header)} (a comma as the decimal separator?)')
    return header, list(rows[1:]), list(lines[1:])


def _our_names(header, ours):
    """``header`` with each name of ``ours`` that no column has exactly taken from a column
    that has it in another case: 'WX' is wx (an index's spin under upper-case names was left
    alone as another column, and the set read as without measured spin; a walk-through,
    7 Dec 2026), while 't,x,y,z,X,Y,Z' keeps x, y, z and leaves X, Y, Z alone."""
    named = list(header)
    for name in ours:
        if name not in header:
            named = [name if h.lower() == name else n for h, n in zip(header, named,
                                                                     strict=True)]
    return named


NOT_MEASURED = ('', 'nan', 'na', 'n/a', '#n/a', 'null', 'none')
"""Cells that mean a value not measured (pandas and MATLAB write NaN, R NA, a spreadsheet
#N/A or nothing), in any case."""


def _number(cell):
    """A CSV cell's value: NaN for one of :data:`NOT_MEASURED`; ValueError otherwise."""
    return math.nan if cell.lower() in NOT_MEASURED else float(cell)


def read_track_csv(path):
    """Read one trajectory CSV (header ``t,x,y,z``, then any other columns; the four may
    come in any order, names in any case) into ``(t, p)``. An empty cell, NaN or NA
    (:data:`NOT_MEASURED`) is a value not measured: its row is dropped later with the other
    non-finite ones."""
    header, rows, lines = _read_csv(path)
    need = ('t', 'x', 'y', 'z')
    header = _our_names(header, need)
    if not set(need) <= set(header):
        raise DataError(f"{path}: header must name the columns 't,x,y,z', "
                        f"got '{','.join(header)}'")
    twice = [name for name in need if header.count(name) > 1]
    if twice:
        raise DataError(f"{path}: header names the column '{twice[0]}' {header.count(twice[0])} "
                        'times: which one is meant?')
    cols = [header.index(name) for name in need]
    values = np.empty((len(rows), 4))
    for i, row in enumerate(rows):
        if len(row) <= max(cols):
            raise DataError(f'{path}: line {lines[i]} has {len(row)} columns, expected '
                            f'{max(cols) + 1}')
        for j, col in enumerate(cols):
            cell = row[col].strip()
            try:
                values[i, j] = _number(cell)
            except ValueError:
                raise DataError(f"{path}: line {lines[i]}, column '{header[col]}': "
                                f'{cell!r} is not a number') from None
    reason = (position_error(values[:, 1:4], 'x, y, z', most=True, lines=lines)   # mm
              or time_error(values[:, 0]) or sample_time_error(values[:, 0]))
    if reason:
        raise DataError(f'{path}: {reason}')
    return values[:, 0], values[:, 1:4]


SPIN_SOURCES = ('measured', 'estimated')
"""Values of index.csv's optional ``spin_source`` column ('' = measured where spin is given)."""


def index_path(folder):
    """The path of a trajectory folder's index file: index.csv in any case (an Index.csv was
    skipped as a track and its measured spin lost without a word: a researcher's walk-through,
    6 Dec 2026), the lower-case name where there is none. Raises DataError for two."""
    try:
        names = [n for n in os.listdir(folder) if n.lower() == 'index.csv']
    except OSError:
        names = []
    if len(names) > 1:
        raise DataError(f'{folder}: {" and ".join(sorted(names))}: two index files, which one '
                        'is meant?')
    return os.path.join(folder, names[0] if names else 'index.csv')


INDEX_SPIN = ('wx', 'wy', 'wz')
"""index.csv's spin columns (rad/s, table frame): all three or none."""


def read_index(path):
    """index.csv of a trajectory folder: {file: (spin or None, label, spin_source)}; {} when
    absent. Its columns are found by name, in any order: ``file`` (required), ``wx, wy, wz``,
    ``label``, ``spin_source``; others (pandas' row numbers, a note) are left alone. Spin
    given as ``estimated`` is not returned as spin (it is not a measurement). ``path``: the
    folder's :func:`index_path`."""
    if not os.path.exists(path):
        return {}
    header, rows, lines = _read_csv(path)
    header = _our_names(header, ('file', *INDEX_SPIN, 'label', 'spin_source'))
    spin_named = [c for c in INDEX_SPIN if c in header]
    if 'file' not in header or 0 < len(spin_named) < 3:
        raise DataError(f"{path}: header must name the column 'file', and 'wx,wy,wz' for "
                        f"measured spin (all three or none), got '{','.join(header)}'")
    twice = [c for c in ('file', *INDEX_SPIN, 'label', 'spin_source') if header.count(c) > 1]
    if twice:
        raise DataError(f"{path}: header names the column '{twice[0]}' "
                        f'{header.count(twice[0])} times: which one is meant?')
    file_col = header.index('file')
    spin_cols = [header.index(c) for c in spin_named]
    label_col = header.index('label') if 'label' in header else None
    source_col = header.index('spin_source') if 'spin_source' in header else None
    index = {}
    for i, row in enumerate(rows):
        row = row + [''] * (len(header) - len(row))
        cells = [row[c].strip() for c in spin_cols]
        spin = None
        if any(c.lower() not in NOT_MEASURED for c in cells):
            try:
                spin = np.array([float(c) for c in cells])
            except ValueError:
                raise DataError(f'{path}: line {lines[i]}: spin {cells} is not three numbers'
                                ) from None
            if not np.all(np.isfinite(spin)):
                raise DataError(f'{path}: line {lines[i]}: spin {cells} is not finite')
            if np.linalg.norm(spin) > MAX_SPIN:         # rpm or rps for rad/s: c_m fitted off
                raise DataError(f'{path}: line {lines[i]}: spin {np.linalg.norm(spin):.0f} rad/s '
                                f'is above {MAX_SPIN:g} rad/s: not a table-tennis ball '
                                '(wx, wy, wz are in rad/s)')
        source = row[source_col].strip().lower() if source_col is not None else ''
        if source and source not in SPIN_SOURCES:
            raise DataError(f"{path}: line {lines[i]}: spin_source '{source}' is not one of "
                            f"{', '.join(SPIN_SOURCES)}")
        if source == 'measured' and spin is None:
            raise DataError(f"{path}: line {lines[i]}: spin_source 'measured' but no spin given")
        if spin is not None and not source:
            source = 'measured'
        if source == 'estimated':
            spin = None
        label = row[label_col].strip() if label_col is not None else ''
        name = row[file_col].strip()
        if not name:                # 'names , not in the folder', no line
            raise DataError(f"{path}: line {lines[i]}: its 'file' is empty")
        if name in index:           # the last row won, without a word
            raise DataError(f'{path}: line {lines[i]}: {name} is named by an earlier row too')
        index[name] = (spin, label, source)
    return index


def folder_tracks(folder):
    """The track CSV files of a trajectory folder, sorted, and its index.csv.

    Parameters
    ----------
    folder : str
        A folder of one CSV per track (t (s), x, y, z (m), table frame) and an optional
        index.csv.

    Returns
    -------
    files : list of str
        The CSV file names (index.csv excluded).
    index : dict
        :func:`read_index` of the folder.

    Raises DataError (naming the folder) for one that is not a folder, cannot be listed or
    holds no track file, and (naming index.csv) for an index row whose file is not there: the
    spin and label it gives would belong to no track, or a track file was lost.
    """
    if not os.path.isdir(folder):
        raise DataError(f'{folder}: not a folder of track CSV files')
    try:
        # .csv in any case (a .CSV from another system is a track file too).
        # Not a hidden file: a copy from a Mac leaves ._0000.csv beside 0000.csv, which is
        # no text, and the set was refused for it (a walk-through).
        files = sorted(f for f in os.listdir(folder)
                       if f.lower().endswith('.csv') and f.lower() != 'index.csv'
                       and not f.startswith('.'))
    except OSError as exc:
        raise DataError(f'{folder}: cannot list: {exc.strerror}') from None
    if not files:
        raise DataError(f'{folder}: ' + ('a rosbag2 bag, not a folder of track CSV files '
                                         '(tt-perceive --out writes one)' if is_bag(folder)
                                         else 'no trajectory CSV files in the folder'))
    index_file = index_path(folder)
    index = read_index(index_file)
    missing = sorted(set(index) - set(files))
    if missing:
        more = f' and {len(missing) - 1} more' if len(missing) > 1 else ''
        raise DataError(f'{index_file}: names {missing[0]}{more}, '
                        'not in the folder')
    return files, index


def load_folder(folder):
    """All tracks of a trajectory folder (one CSV per track plus optional index.csv)."""
    files, index = folder_tracks(folder)
    tracks = []
    for name in files:
        path = os.path.join(folder, name)
        t, p = read_track_csv(path)
        t, p, notes = clean_samples(path, t, p)
        if len(t) < 2:
            raise DataError(f'{path}: {len(t)} valid sample(s); a trajectory needs at least 2')
        spin, label, spin_source = index.get(name, (None, '', ''))
        source = os.path.basename(os.path.normpath(folder))
        tracks.append(Track(f'{source}/{name}', t, p, spin, label, notes, spin_source))
    return tracks


def _bag_typestore():
    """A rosbags typestore for Jazzy with tt_msgs' BallState registered from its installed .msg
    file (tt_ros.bagfile.TypeRegistry; without it, bags of PointStamped still load)."""
    from tt_ros.bagfile import BagError, TypeRegistry
    registry = TypeRegistry()
    try:
        registry.ensure('tt_msgs/msg/BallState')
    except BagError:        # tt_msgs not installed
        pass
    return registry.store


BAG_TYPES = ('tt_msgs/msg/BallState', 'geometry_msgs/msg/PointStamped')
TRACK_GAP = 0.25
"""A bag's stream is split into tracks at gaps longer than this, or at a new track_id, s."""


def load_bag(path, topic=None):
    """Tracks from a rosbag2 bag of BallState or PointStamped (header stamps).

    ``topic``: the topic to read; by default the only topic of a supported type. BallState
    messages are split by ``track_id``; PointStamped streams at gaps over TRACK_GAP.
    """
    from rosbags.highlevel import AnyReader
    from tt_ros.bagfile import bag_problem
    problem = bag_problem(path)
    if problem:
        raise DataError(f'{path}: not a readable rosbag2 bag: {problem}')
    try:
        reader = AnyReader([pathlib.Path(path)], default_typestore=_bag_typestore())
        reader.open()
    except Exception as exc:     # rosbags raises several unrelated types for a bad bag
        raise DataError(f'{path}: not a readable rosbag2 bag: {one_line_reason(exc)}') from None
    try:
        conns = [c for c in reader.connections if c.msgtype in BAG_TYPES
                 and (topic is None or c.topic == topic)]
        if not conns:
            present = ', '.join(sorted({f'{c.topic} ({c.msgtype})'
                                        for c in reader.connections})) or 'none'
            wrong = sorted({c.msgtype for c in reader.connections if c.topic == topic})
            if wrong:
                raise DataError(f"{path}: topic '{topic}' is {', '.join(wrong)}, not "
                                f"{' or '.join(BAG_TYPES)}")
            want = f"topic '{topic}'" if topic else 'BallState or PointStamped topic'
            raise DataError(f'{path}: no {want} in the bag (topics: {present})')
        if len({c.topic for c in conns}) > 1:
            raise DataError(f'{path}: several candidate topics, choose one with --topic')
        rows = []
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            point = msg.position if hasattr(msg, 'position') else msg.point
            spin = msg.spin if hasattr(msg, 'spin') else None
            rows.append((getattr(msg, 'track_id', 0), stamp, point.x, point.y, point.z,
                         (spin.x, spin.y, spin.z) if spin is not None else None))
    finally:
        reader.close()
    return _tracks_from_stream(path, rows)


def _tracks_from_stream(path, rows):
    """Split (track_id, t, x, y, z, spin) rows into tracks by id and by gaps."""
    source = os.path.basename(os.path.normpath(path))
    tracks = []
    for track_id in sorted({r[0] for r in rows}):
        sel = sorted((r for r in rows if r[0] == track_id), key=lambda r: r[1])
        t = np.array([r[1] for r in sel])
        p = np.array([r[2:5] for r in sel], dtype=float)
        cuts = np.flatnonzero(np.diff(t) > TRACK_GAP) + 1
        for k, (a, b) in enumerate(zip([0, *cuts], [*cuts, len(t)], strict=True)):
            tt, pp, notes = clean_samples(path, t[a:b], p[a:b])
            if len(tt) < 2:
                continue
            # A BallState's spin is perception's estimate, never a measurement: the track is
            # fitted with its spin unknown (all zeros: the publisher had no estimate).
            spin = sel[a][5]
            spin_source = 'estimated' if spin is not None and any(spin) else ''
            tracks.append(Track(f'{source}/{track_id}.{k}', tt - tt[0], pp, None, '', notes,
                                spin_source))
    if not tracks:
        raise DataError(f'{path}: no track with at least 2 samples in the bag')
    return tracks


def is_bag(path):
    """Whether ``path`` is read as a rosbag2 bag: a file, or a folder holding a bag's
    metadata.yaml or storage files."""
    return os.path.isfile(path) or any(
        f == 'metadata.yaml' or f.endswith(('.mcap', '.db3')) for f in os.listdir(path))


def load(paths, topic=None):
    """Tracks of every DATA argument (trajectory folder or bag); DataError on bad input."""
    tracks, seen = [], {}
    for path in paths:
        if not os.path.exists(path):
            raise DataError(f'{path}: no such file or folder')
        real = os.path.realpath(path)
        if real in seen:
            raise DataError(f'{path}: given twice (as {seen[real]}): its tracks would count '
                            'twice')
        seen[real] = path
        if os.path.isfile(path) and path.lower().endswith('.csv'):
            raise DataError(f'{path}: a track file; DATA is the folder of track CSV files '
                            '(with its index.csv) or a rosbag2 bag')
        tracks.append(load_bag(path, topic) if is_bag(path) else load_folder(path))
    given = [os.path.abspath(path) for path in seen.values()]
    labels = source_labels(given)
    for path, group in zip(given, tracks, strict=True):      # unique names across sources
        for tr in group:            # '<folder as given>/<file>': the folder's label instead
            tr.name = f"{labels[path]}/{tr.name.split('/', 1)[1]}"
    return [tr for group in tracks for tr in group]


def source_labels(paths):
    """{absolute path: its shortest trailing part that no other of ``paths`` shares}: the
    base name, or more of the path where two sources have the same base name."""
    parts = {p: pathlib.PurePath(os.path.normpath(p)).parts for p in paths}
    labels = {}
    for p in paths:
        for k in range(1, len(parts[p]) + 1):
            label = '/'.join(parts[p][-k:])
            if not any(o != p and '/'.join(parts[o][-k:]) == label for o in paths):
                break
        labels[p] = label
    return labels


def nominal_rate(tracks):
    """Median sample rate over the tracks, Hz."""
    dts = np.concatenate([np.diff(tr.t) for tr in tracks])
    return 1.0 / float(np.median(dts)) if len(dts) else math.nan
