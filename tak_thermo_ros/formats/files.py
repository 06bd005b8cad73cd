"""Output files: written atomically, only as regular files and directories, one overwrite rule.

Every output of ``tak_calib`` (calibration YAML, JSON, report directory, bag directory) obeys
one rule:

- an output that does not exist yet is written to a temporary ``.NAME.*.partial`` beside it
  and renamed into place, so that an interrupted or failed write leaves nothing behind;
- an existing output is refused (:class:`~tak_thermo_ros.errors.OutputError`, one line telling
  to remove it or pass ``--force``);
- with ``--force``, an existing *regular file* (YAML, JSON), an existing *bag directory*
  (``metadata.yaml`` and plain files) or an existing *report directory* (``report.html`` and
  PNG figures) is replaced; the new output is complete before the old one goes;
- anything else is refused, with or without ``--force``: a symbolic link, a FIFO, a device
  node, a socket, a directory where a file is expected, a directory that is not a bag or a
  report. Nothing but regular files and the output directories is ever replaced.

Errors name the user's path, never the temporary one.

No JSON or YAML this tool writes holds a non-finite number (JSON has none; a NaN in a YAML
file is a number nobody can use): :func:`json_text`, :func:`check_finite_yaml` and
:func:`write_texts` refuse one, naming the file and the key (:func:`check_finite`). A value
that is not defined is said where it arises (``null`` with its meaning documented, or left out
with a line), never written as NaN or infinity.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import stat
import tempfile
from pathlib import Path
from typing import Any, Iterator

from tak_thermo_ros.errors import OutputError, TakError

FILE = 'file'
BAG = 'bag'
REPORT = 'report'
OUTPUT_KINDS = (FILE, BAG, REPORT)
"""What an output is: a regular file, a rosbag2 directory, a report directory."""

_REPORT_SUFFIXES = ('.png', '.html')


def file_kind(mode: int) -> str:
    """A file type in words (``a symbolic link``, ``a FIFO (named pipe)``, ...)."""
    for test, name in ((stat.S_ISLNK, 'a symbolic link'), (stat.S_ISFIFO, 'a FIFO (named pipe)'),
                       (stat.S_ISCHR, 'a character device'), (stat.S_ISBLK, 'a block device'),
                       (stat.S_ISSOCK, 'a socket'), (stat.S_ISDIR, 'a directory'), (stat.S_ISREG, 'a regular file')):
        if test(mode):
            return name
    return 'a special file'


def _is_output_directory(path: Path, kind: str) -> bool:
    """Whether an existing directory is one this tool writes (a bag or a report) of ``kind``."""
    try:
        entries = list(os.scandir(path))
    except OSError:
        return False
    if not all(entry.is_file(follow_symlinks=False) for entry in entries):
        return False
    names = {entry.name for entry in entries}
    if not names:
        return True  # an empty directory holds nothing to lose
    if kind == BAG:
        return 'metadata.yaml' in names
    return 'report.html' in names and all(name.endswith(_REPORT_SUFFIXES) for name in names)


def check_output(path: str | os.PathLike[str], kind: str = FILE, *, force: bool = False,
                 option: str = '') -> Path:
    """Check that ``path`` may be written as an output of ``kind`` under the overwrite rule.

    :param kind: one of :data:`OUTPUT_KINDS`.
    :param force: replace an existing output of the same kind (``--force``).
    :param option: the command-line option naming the output, for the message.
    :raises OutputError: one line naming ``path``.
    """
    path = Path(path)
    label = f'{path} ({option})' if option else str(path)
    what = {FILE: 'a regular file', BAG: 'a bag directory', REPORT: 'a report directory'}[kind]
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        parent = path.parent
        if not parent.is_dir():
            msg = f'{label}: cannot write into directory {parent}: No such file or directory'
            raise OutputError(msg) from None
        return path
    except OSError as err:
        msg = f'{label}: cannot inspect ({err.strerror})'
        raise OutputError(msg) from None
    if kind == FILE:
        matches = stat.S_ISREG(mode)
    else:
        matches = stat.S_ISDIR(mode) and _is_output_directory(path, kind)
    if not matches:
        msg = (f'{label}: exists and is {file_kind(mode)}'
               f'{" that this tool did not write" if stat.S_ISDIR(mode) and kind != FILE else ""}; '
               f'only {what} is written or replaced here, refusing to touch it')
        raise OutputError(msg)
    if not force:
        msg = f'{label}: exists already, not overwriting (remove it or pass --force)'
        raise OutputError(msg)
    return path


def _temporary_parent(path: Path) -> Path:
    return path.parent if str(path.parent) else Path('.')


def _user_error(err: OSError, path: Path) -> OSError:
    """The same error naming the user's path instead of a temporary one."""
    return OSError(err.errno, err.strerror or str(err), str(path))


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write a text file (UTF-8) atomically, as :func:`write_bytes_atomic`."""
    write_bytes_atomic(path, text.encode('utf-8'))


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write a file atomically: a temporary file beside it, then a rename.

    An existing regular file is replaced (the caller applies the overwrite rule with
    :func:`check_output`); anything else that exists (a link, a FIFO, a device, a directory)
    is refused.

    :raises OutputError: ``path`` exists and is not a regular file.
    :raises OSError: the write failed (disk full, no permission), naming ``path``; nothing
        is left behind.
    """
    path = Path(path)
    with contextlib.suppress(FileNotFoundError):
        mode = os.lstat(path).st_mode
        if not stat.S_ISREG(mode):
            msg = f'{path}: exists and is {file_kind(mode)}; only a regular file is written here, refusing to touch it'
            raise OutputError(msg)
    try:
        handle, temporary = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.partial',
                                             dir=_temporary_parent(path))
    except OSError as err:
        raise _user_error(err, path) from None
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(temporary, 0o666 & ~umask)  # mkstemp makes it owner-only; a normal file is wanted
        with os.fdopen(handle, 'wb') as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except OSError as err:
        Path(temporary).unlink(missing_ok=True)
        raise _user_error(err, path) from None
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def non_finite_number(document: Any, where: str = '') -> tuple[str, float] | None:
    """The key path (``sensors.accel.allan_floor[2]``) and value of the first NaN or infinity in ``document``.

    ``document``: mappings, lists, tuples and numbers (JSON- or YAML-like); ``None`` when every
    number is finite.
    """
    if isinstance(document, float) or (hasattr(document, 'dtype') and getattr(document, 'shape', None) == ()):
        try:
            value = float(document)
        except (TypeError, ValueError):
            return None
        return None if math.isfinite(value) else (where or 'the document', value)
    if isinstance(document, dict):
        items = ((f'{where}.{key}' if where else str(key), value) for key, value in document.items())
    elif isinstance(document, (list, tuple)):
        items = ((f'{where}[{index}]', value) for index, value in enumerate(document))
    else:
        return None
    for key, value in items:
        found = non_finite_number(value, key)
        if found is not None:
            return found
    return None


def check_finite(document: Any, path: str | os.PathLike[str]) -> None:
    """Refuse a document holding a NaN or infinity: the one check before any JSON or YAML is written.

    :raises OutputError: one line naming ``path``, the key and the value; nothing is written.
    """
    found = non_finite_number(document)
    if found is not None:
        key, value = found
        msg = f'{path}: {key} is {value} (not a finite number); not written'
        raise OutputError(msg)


def json_text(document: Any, path: str | os.PathLike[str]) -> str:
    """A JSON document's text, indented; one holding a non-finite number is refused (:func:`check_finite`)."""
    check_finite(document, path)
    return json.dumps(document, indent=2, allow_nan=False) + '\n'


def write_json(path: str | os.PathLike[str], document: Any) -> None:
    """Write a JSON document atomically (:func:`json_text`, :func:`write_text_atomic`)."""
    write_text_atomic(path, json_text(document, path))


def check_finite_yaml(text: str, path: str | os.PathLike[str]) -> None:
    """Refuse a YAML text that holds a non-finite number (``.nan``, ``.inf``), read back as it is written."""
    import yaml
    check_finite(yaml.safe_load(text), path)


def _check_text(path: Path, text: str) -> None:
    """A JSON or YAML file's text (by its suffix), checked as :func:`check_finite`."""
    if path.suffix == '.json':
        def refuse(constant: str) -> float:
            return float(constant)  # NaN, Infinity: found by check_finite
        check_finite(json.loads(text, parse_constant=refuse), path)
    elif path.suffix in ('.yaml', '.yml'):
        check_finite_yaml(text, path)


def write_texts(directory: str | os.PathLike[str], texts: dict[str, str]) -> tuple[Path, ...]:
    """Write each ``name: text`` into ``directory`` (made if missing), each file atomically; their paths.

    A ``.json`` or ``.yaml`` text holding a non-finite number is refused before any is written.
    """
    directory = Path(directory)
    paths = tuple(directory / name for name in texts)
    for path, text in zip(paths, texts.values()):
        _check_text(path, text)
    directory.mkdir(parents=True, exist_ok=True)
    for path, text in zip(paths, texts.values()):
        write_text_atomic(path, text)
    return paths


def staging_directory(path: Path) -> Path:
    """A new empty hidden ``.NAME.*.partial`` directory beside ``path``.

    :raises OSError: naming ``path`` when it cannot be made.
    """
    try:
        return Path(tempfile.mkdtemp(prefix=f'.{path.name}.', suffix='.partial', dir=_temporary_parent(path)))
    except OSError as err:
        raise _user_error(err, path) from None


def install_directory(finished: Path, path: Path) -> None:
    """Rename a finished directory to ``path``, replacing an existing output there.

    The old output is renamed aside first and removed only after the new one is in place;
    should the second rename fail, the old one is put back.
    """
    old = None
    if os.path.lexists(path):
        old = Path(tempfile.mkdtemp(prefix=f'.{path.name}.', suffix='.old', dir=_temporary_parent(path)))
        aside = old / 'previous'
        os.rename(path, aside)
    try:
        os.rename(finished, path)
    except BaseException:
        if old is not None:
            os.rename(old / 'previous', path)
            shutil.rmtree(old, ignore_errors=True)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Fill a staging directory and rename it to ``path`` on success.

    On any failure or interruption remove it, leaving ``path`` as it was.

    The caller applies the overwrite rule (:func:`check_output`) beforehand.
    """
    path = Path(path)
    staging = staging_directory(path)
    inner = staging / path.name
    inner.mkdir()
    try:
        try:
            yield inner
            install_directory(inner, path)
        except OSError as err:  # a full disk while filling it: name the user's path
            raise _user_error(err, path) from err
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def not_regular(path: str | os.PathLike[str]) -> str:
    """What ``path`` is when it exists and is no regular file (``a FIFO (named pipe)``), else ``''``.

    Follows a symbolic link (a link to a regular file is read as one); never opens the path.
    """
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return ''
    return '' if stat.S_ISREG(mode) else file_kind(mode)


def read_regular_bytes(path: str | os.PathLike[str], what: str, error: type[TakError]) -> bytes:
    """The bytes of a regular file; anything else refused in one line, without waiting on it.

    Opened with ``O_NONBLOCK`` and judged by ``fstat`` before any read: a FIFO (which would block the
    open, or the read, until a writer comes), a socket, a device (``/dev/zero`` never ends) or a
    directory is refused, naming what it is.

    :param what: the file's name in a message (``'calibration file'``).
    :raises FileNotFoundError: it does not exist (the caller says so in its words).
    :raises error: one line naming the file, when it is no regular file or cannot be read.
    """
    try:
        handle = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, 'O_CLOEXEC', 0))
    except FileNotFoundError:
        raise
    except OSError as err:  # a socket (ENXIO), no permission
        kind = not_regular(path)
        msg = (f'{path}: is {kind}, not a {what}: only a regular file is read' if kind
               else f'{path}: cannot read the {what} ({err.strerror})')
        raise error(msg) from None
    mode = os.fstat(handle).st_mode
    if not stat.S_ISREG(mode):
        os.close(handle)
        msg = f'{path}: is {file_kind(mode)}, not a {what}: only a regular file is read'
        raise error(msg)
    os.set_blocking(handle, True)
    with os.fdopen(handle, 'rb') as stream:
        try:
            return stream.read()
        except OSError as err:
            msg = f'{path}: cannot read the {what} ({err.strerror})'
            raise error(msg) from None


def read_yaml(path: str | os.PathLike[str], what: str, error: type[TakError]) -> Any:
    """The YAML document in ``path`` (``None`` for an empty file).

    :param what: the file's name in a message (``'noise file'``, ``'scenario file'``).
    :raises error: one line naming the file when it is missing, unreadable or not YAML.
    """
    import yaml
    path = Path(path)
    try:
        return yaml.safe_load(read_regular_bytes(path, what, error).decode('utf-8'))
    except FileNotFoundError:
        msg = f'{path}: no such {what}'
        raise error(msg) from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        msg = f'{path}: cannot read the {what} ({type(err).__name__})'
        raise error(msg) from None
    except (RecursionError, ValueError) as err:  # nested beyond Python's stack; an integer of 4,300+ digits
        msg = f'{path}: cannot read the {what} ({unreadable(err)})'
        raise error(msg) from None


def unreadable(err: RecursionError | ValueError) -> str:
    """Why a YAML document cannot be taken, in a few words (the error's own text runs long)."""
    if isinstance(err, RecursionError):
        return 'nested too deeply'
    if 'digits' in str(err):
        return 'an integer of more digits than Python converts'
    return str(err).splitlines()[0] if str(err) else type(err).__name__
