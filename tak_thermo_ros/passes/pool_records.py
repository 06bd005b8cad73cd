"""The records of a pool: the paths named (a record, or a directory of them), each record once, and where to write them.

``tak_calib fit|validate|diagnose|apply`` take a pool when given several records or a directory
that is not a bag (:func:`is_pool`); :func:`record_paths` finds its records, :func:`distinct_records`
counts a second copy of a record once. Reading them: :mod:`~tak_thermo_ros.passes.pool`.
"""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from tak_thermo_ros.errors import FitError, TakError

if TYPE_CHECKING:
    from tak_thermo_ros.formats.records import Record

RECORD_SUFFIXES = ('.ulg', '.bin')
"""A file in a directory of records is a record when it is named so (a bag is a directory with metadata.yaml)."""


class PoolError(FitError):
    """A pool that cannot be fitted as one unit's records (in one line)."""


def is_bag(path: Path) -> bool:
    """A rosbag2 directory (its metadata.yaml)."""
    return path.is_dir() and (path / 'metadata.yaml').is_file()


def record_paths(paths: Sequence[str | os.PathLike[str]]) -> tuple[list[Path], list[str]]:
    """The records named: each path a record, or a directory of records (bags, ``.ulg``, ``.bin``, sorted by name).

    :returns: the records, and one line per directory that holds entries that are no record.
    :raises PoolError: a path that does not exist, a directory without a record.
    """
    records: list[Path] = []
    lines: list[str] = []
    for given in paths:
        path = Path(given)
        if not path.exists():
            msg = f'{path}: no such record or directory'
            raise PoolError(msg)
        if not path.is_dir() or is_bag(path):
            records.append(path)
            continue
        found, other = [], []
        for entry in sorted(path.iterdir()):
            if is_bag(entry) or (entry.is_file() and entry.suffix.lower() in RECORD_SUFFIXES):
                found.append(entry)
            else:
                other.append(entry.name)
        if not found:
            msg = f'{path}: no record in it (bags, .ulg or .bin logs)'
            raise PoolError(msg)
        if other:
            shown = ', '.join(other[:3]) + (', ...' if len(other) > 3 else '')
            lines.append(f'{path}: {len(other)} entries are no record, not read ({shown})')
        records += found
    return records, lines


def _spelled(paths: Sequence[str | os.PathLike[str]], records: Sequence[Path]) -> list[str]:
    """Each record as the user spelled it (``./month/rec00/``); a directory's records by their paths."""
    given: dict[Path, list[str]] = {}
    for path in paths:
        given.setdefault(Path(path), []).append(os.fspath(path))
    return [given[path].pop(0) if given.get(path) else str(path) for path in records]


def same_how(path: str | os.PathLike[str], earlier: str | os.PathLike[str], content: str) -> str:
    """How a second copy is the first: ``through a link``, ``the same path``, else ``content`` (a copy)."""
    if os.path.realpath(path) != os.path.realpath(earlier):
        return content or 'the same content'
    return 'through a link' if os.path.realpath(path) != os.path.abspath(path) else 'the same path'


def distinct_records(records: Sequence[Record], spelled: Sequence[str] | None = None) -> tuple[list[int], list[str]]:
    """The records that are not a second copy of an earlier one, by content (:attr:`Record.identity`).

    A record given twice (another spelling of its path, a link, a copy, a bag's ``.mcap`` beside its
    folder, one flight as ``.ulg`` and ``.bin``) is one power-up: counted once, the second named.

    Only records of the same message count and last log time are read for their identity (the others
    cannot be the same).

    :returns: the indices of the records kept, and one line per second copy (an unreadable record is said
        when it is read).
    """
    names = list(spelled) if spelled is not None else [str(record) for record in records]
    counted = []
    for record in records:
        try:
            streams = record.streams
        except TakError:  # unreadable: said when it is read
            streams = None
        counted.append(streams)
    counts = Counter((s.kind, s.main, s.end_ns) for s in counted if s is not None)
    first: dict[object, int] = {}
    kept, lines = [], []
    for index, (record, streams) in enumerate(zip(records, counted)):
        alone = streams is None or counts[streams.kind, streams.main, streams.end_ns] == 1
        identity = None if alone else record.identity
        key = identity if identity is not None else ('path', os.path.realpath(record.path))
        if key in first:
            earlier = first[key]
            how = same_how(record.path, records[earlier].path,
                           f'the same {identity.messages} messages' if identity else '')
            lines.append(f'{names[index]}: the same record as {names[earlier]} ({how}): counted once')
            continue
        first[key] = index
        kept.append(index)
    return kept, lines


def is_pool(paths: Sequence[str | os.PathLike[str]]) -> bool:
    """Whether the records given make a pool: several, or a directory that is not a bag."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    return len(paths) > 1 or (Path(paths[0]).is_dir() and not is_bag(Path(paths[0])))


def bag_directory(path: str | os.PathLike[str], *, force: bool, option: str) -> Path:
    """A directory to write one bag per record into: made, or one that holds only bags (``force`` replaces them).

    :raises OutputError: ``path`` is no directory, holds something else than bags, or holds bags without ``force``.
    """
    import shutil
    from tak_thermo_ros.errors import OutputError
    from tak_thermo_ros.formats.files import BAG, check_output
    out = Path(path)
    if out.exists() or out.is_symlink():
        if out.is_symlink() or not out.is_dir():
            msg = f'{out} ({option}): exists and is not a directory; the records are written into a directory'
            raise OutputError(msg)
        entries = sorted(out.iterdir())
        for entry in entries:  # only bags this tool wrote may be replaced
            check_output(entry, BAG, force=True, option=option)
        if entries and not force:
            msg = f'{out} ({option}): exists and holds {len(entries)} bags; --force replaces them'
            raise OutputError(msg)
        for entry in entries:
            shutil.rmtree(entry)
    else:
        check_output(out, BAG, option=option)
        out.mkdir()
    return out
