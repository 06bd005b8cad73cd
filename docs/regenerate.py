r"""Docs that cannot drift: run the ``console`` transcripts of the README and docs/, check them or regenerate them.

The convention (every doc follows it; ``test/project/test_docs.py`` checks it, this script regenerates):

- A transcript is a fenced block whose info string starts with ``console``. Other blocks (``sh``,
  ``yaml``, plain) are never run.
- A line that starts with ``$ `` is a command; a command line that ends with `` \`` goes on on the
  next line. The lines after a command, up to the next command or the block's end, are a
  selection of what it prints (stdout and stderr together): each must appear in that order in
  what it prints (other lines may come between them).
- Comparing a shown line with a printed one: runs of white space count as one space; ``...`` in
  a line stands for any text (none included); a line that is only ``...`` says that lines were
  left out and is not compared; every number is compared by value. A shown number matches a
  printed one within one unit of its own last digit (``0.61`` matches 0.60 to 0.62, ``6031``
  matches 6030 to 6032: the last digit may round the other way on another machine); a block's
  info string ``tolerance=5%`` (relative to the printed value) or ``tolerance=0.01`` (absolute)
  adds to that, and a shown line that ends in `` [~5%]`` or `` [~0.01]`` has its own (the marker
  is not compared).
- A command must exit with status 0, unless its last shown line is ``[N]``: then it must exit with N.
- A command that ends in `` &`` runs in the background (a node); it is stopped with SIGINT at the
  end of its block, and its shown lines are compared with what it printed until then.
- ``console slow`` marks a block that the test does not run (minutes, or a node and DDS); this
  script runs every block. A block after a slow one must not need what the slow one made (mark
  it slow as well).
- Where the commands run: each doc file in a temporary directory of its own, its commands in
  the order of the file, as a reader runs the page (so no command may write an output an earlier
  one of the page wrote, slow blocks included, unless with ``--force``: :func:`overwritten`);
  the repository's top level is there as links (``docs``, ``data``, the ``Makefile``, ...), so a
  doc names a shipped scenario by its path,
  ``docs/scenarios/NAME.yaml``, as a user does from the repository's root, and what the
  commands write stays in the temporary directory. ``tak_calib`` and ``compensator`` are the
  virtual environment's.
- No line a ``tak_calib`` command (or ``make demo``) prints may be longer than :data:`MAX_LINE`
  characters (an error, one line by the tool's rule, excepted).

Usage::

    .venv/bin/python docs/regenerate.py                 # every doc: numbers brought up to date, in place
    .venv/bin/python docs/regenerate.py docs/noise.md   # one doc
    .venv/bin/python docs/regenerate.py --check         # compare only (what the test does, slow blocks too)
    .venv/bin/python docs/regenerate.py --full docs/x.md  # a command's shown lines become all it prints

Regenerating keeps each doc's selection of lines and its words, and writes the numbers the tool
prints now; a shown line whose words the tool no longer prints is reported (exit 1), for a
person to edit.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import shlex
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

ROOT = Path(__file__).resolve().parents[1]
DOCS = (ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md')))
"""The files whose ``console`` blocks are transcripts."""
MAX_LINE = 100
"""The longest line a ``tak_calib`` command may print."""
ERROR = 'tak_calib: error:'
LINE_CHECKED = ('tak_calib', 'make')
"""The commands whose every line :data:`MAX_LINE` holds: the tool, and ``make demo`` (which runs it)."""
"""An error is one line by the tool's rule, however long: the only line exempt from :data:`MAX_LINE`."""
BACKGROUND_STOP_S = 20.0
"""How long a background command has to exit after SIGINT before it is killed."""
NUMBER = re.compile(r'(?<![A-Za-z_\d.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?')
"""A number in a line: not part of a name (``run2``, ``imu0``); ``5.68..34.18`` is two numbers."""
LINE_TOLERANCE = re.compile(r'\s+\[~(\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)(%?)\]\s*$')
EXIT = re.compile(r'^\[(\d+)\]$')
SHELL = re.compile(r'[|&;<>()$`*?~]|\\$')
"""Characters that need a shell; a ``tak_calib`` command without them runs in this process."""


@dataclass(frozen=True)
class Tolerance:
    """How far a shown number may lie from the printed one: relative, or absolute."""

    relative: float = 0.0
    absolute: float = 0.0

    @classmethod
    def parse(cls, value: str, percent: bool) -> Tolerance:
        """``5`` with ``%``: relative 0.05; without: absolute 5."""
        if percent:
            return cls(relative=float(value) / 100.0, absolute=0.0)
        return cls(relative=0.0, absolute=float(value))

    def allows(self, shown: str, printed: str) -> bool:
        """Whether the shown number stands for the printed one."""
        a, b = float(shown), float(printed)
        return abs(a - b) <= _last_digit(shown) * (1.0 + 1e-9) + self.relative * abs(b) + self.absolute


def _last_digit(number: str) -> float:
    """One unit of a written number's last digit: ``0.61`` -> 0.01, ``1.5e-05`` -> 1e-06, ``6031`` -> 1."""
    mantissa, _, exponent = number.lower().partition('e')
    decimals = len(mantissa.partition('.')[2])
    return 10.0 ** (-decimals + (int(exponent) if exponent else 0))


@dataclass
class Shown:
    """A line a doc shows of a command's output."""

    index: int
    text: str
    tolerance: Tolerance | None


@dataclass
class Command:
    """A ``$`` command of a transcript and the lines shown after it."""

    index: int
    last_index: int
    text: str
    shown: list[Shown] = field(default_factory=list)
    exit_status: int = 0

    @property
    def background(self) -> bool:
        """A command that ends in ``&``: a process that runs until the block ends."""
        return self.text.rstrip().endswith('&') and not self.text.rstrip().endswith('&&')


@dataclass
class Block:
    """A ``console`` block: where it stands, its options and its commands."""

    path: Path
    index: int
    slow: bool
    tolerance: Tolerance
    commands: list[Command]


def parse(path: Path, lines: list[str] | None = None) -> list[Block]:
    """The ``console`` blocks of a Markdown file."""
    lines = path.read_text(encoding='utf-8').splitlines() if lines is None else lines
    blocks: list[Block] = []
    i = 0
    while i < len(lines):
        opening = re.match(r'^(\s*)(`{3,}|~{3,})\s*(.*)$', lines[i])
        if not opening:
            i += 1
            continue
        fence, words = opening.group(2), opening.group(3).split()
        end = i + 1
        while end < len(lines) and not lines[end].strip().startswith(fence):
            end += 1
        if words and words[0] == 'console':
            blocks.append(_block(path, i, words[1:], lines[i + 1:end], i + 1))
        i = end + 1
    return blocks


def _block(path: Path, index: int, words: list[str], body: list[str], first: int) -> Block:
    tolerance = Tolerance()
    for word in words:
        found = re.fullmatch(r'tolerance=(\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)(%?)', word)
        if found:
            tolerance = Tolerance.parse(found.group(1), bool(found.group(2)))
        elif word != 'slow':
            msg = f'{path}:{index + 1}: unknown word {word!r} in the console block\'s info string'
            raise ValueError(msg)
    commands: list[Command] = []
    j = 0
    while j < len(body):
        line = body[j]
        if line.startswith('$ '):
            text, start = line[2:], j
            while text.endswith('\\') and j + 1 < len(body):
                j += 1
                text = text[:-1].rstrip() + ' ' + body[j].strip()
            commands.append(Command(index=first + start, last_index=first + j, text=text))
        elif commands and line.strip() and line.strip() != '...':
            found = LINE_TOLERANCE.search(line)
            own = Tolerance.parse(found.group(1), bool(found.group(2))) if found else None
            text = line[:found.start()] if found else line
            exit_status = EXIT.match(text.strip())
            if exit_status:
                commands[-1].exit_status = int(exit_status.group(1))
            else:
                commands[-1].shown.append(Shown(index=first + j, text=text, tolerance=own))
        elif not commands and line.strip():
            msg = f'{path}:{first + j + 1}: output before the first $ command of a console block'
            raise ValueError(msg)
        j += 1
    return Block(path=path, index=index, slow='slow' in words, tolerance=tolerance, commands=commands)


# ----- comparing a shown line with the printed ones -----------------------------------------------------------


def _pattern(shown: str) -> tuple[re.Pattern[str], list[str]]:
    """The regular expression of a shown line (numbers and ``...`` as wildcards) and its numbers."""
    parts: list[str] = []
    numbers: list[str] = []
    text = ' '.join(shown.split())
    position = 0
    for match in NUMBER.finditer(text):
        parts.append(_words(text[position:match.start()]))
        parts.append(r'([-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)')
        numbers.append(match.group())
        position = match.end()
    parts.append(_words(text[position:]))
    return re.compile(''.join(parts)), numbers


def _words(text: str) -> str:
    pieces = [re.escape(piece) for piece in text.split('...')]
    return '.*?'.join(pieces).replace(r'\ ', ' ')


def _matches(shown: Shown, printed: str, tolerance: Tolerance) -> tuple[bool, list[str] | None]:
    """Whether the words match, and whether the numbers do too (their printed values, if the words match)."""
    pattern, numbers = _pattern(shown.text)
    found = pattern.fullmatch(' '.join(printed.split()))
    if found is None:
        return False, None
    values = list(found.groups())
    rule = shown.tolerance or tolerance
    return all(rule.allows(a, b) for a, b in zip(numbers, values)), values


def compare(command: Command, output: str, tolerance: Tolerance) -> list[str]:
    """The shown lines that do not appear, in order, in what the command printed (empty: it agrees)."""
    printed = output.splitlines()
    problems = []
    start = 0
    for shown in command.shown:
        near = None
        for k in range(start, len(printed)):
            numbers_ok, values = _matches(shown, printed[k], tolerance)
            if numbers_ok:
                start = k + 1
                break
            if values is not None and near is None:
                near = printed[k]
        else:
            said = f'; printed with other numbers: {near.strip()!r}' if near is not None else ''
            problems.append(f'line {shown.index + 1}: {shown.text.strip()!r} is not printed (in this order){said}')
    return problems


def updated(command: Command, output: str, lines: list[str]) -> list[str]:
    """Rewrite the command's shown lines in ``lines`` with the numbers printed now; the shown lines not found."""
    printed = output.splitlines()
    missing = []
    start = 0
    for shown in command.shown:
        for k in range(start, len(printed)):
            _, values = _matches(shown, printed[k], Tolerance())
            if values is not None:
                start = k + 1
                lines[shown.index] = _with_numbers(lines[shown.index], values)
                break
        else:
            missing.append(f'line {shown.index + 1}: {shown.text.strip()!r} is not printed (in this order)')
    return missing


def _with_numbers(line: str, values: list[str]) -> str:
    """The doc's line with its numbers replaced, in order, by ``values`` (its words and spacing kept)."""
    marker = LINE_TOLERANCE.search(line)
    body, tail = (line[:marker.start()], line[marker.start():]) if marker else (line, '')
    replacements = iter(values)
    return NUMBER.sub(lambda _: next(replacements), body) + tail


# ----- running a doc's commands -------------------------------------------------------------------------------


@dataclass
class Ran:
    """A command's outcome."""

    status: int
    output: str


class Session:
    """A doc's working directory and environment; runs its commands in order."""

    def __init__(self, directory: Path, *, domain: int = 77) -> None:
        self.directory = directory
        for entry in ROOT.iterdir():  # the repository's top level, as links: docs/scenarios, data, Makefile, .venv
            link = directory / entry.name
            if entry.name != '.git' and (not entry.name.startswith('.') or entry.name == '.venv') \
                    and not link.exists():
                link.symlink_to(entry, target_is_directory=entry.is_dir())
        bin_directory = Path(sys.executable).parent
        ros_home = directory / '.ros'
        ros_home.mkdir(exist_ok=True)
        self.env = {**os.environ, 'PATH': f'{bin_directory}{os.pathsep}{os.environ.get("PATH", "")}',
                    'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                    'ROS_HOME': str(ros_home), 'ROS_LOG_DIR': str(ros_home / 'log'), 'COLUMNS': str(MAX_LINE),
                    'PYTHONUNBUFFERED': '1', 'RCUTILS_COLORIZED_OUTPUT': '0'}
        self.background: list[tuple[Command, subprocess.Popen, Path]] = []

    def run(self, command: Command) -> Ran | None:
        """Run a command (``None`` for a background one, whose outcome :meth:`stop` gives)."""
        text = command.text
        if command.background:
            log = self.directory / f'.background-{len(self.background)}.log'
            with open(log, 'w', encoding='utf-8') as sink:
                process = subprocess.Popen(['bash', '-c', text.rstrip()[:-1]], cwd=self.directory, env=self.env,
                                           stdout=sink, stderr=subprocess.STDOUT, start_new_session=True)
            self.background.append((command, process, log))
            return None
        words = _in_process(text)
        if words is not None:
            return self._tak_calib(words)
        done = subprocess.run(['bash', '-c', text], cwd=self.directory, env=self.env, capture_output=True,
                              text=True, check=False)
        return Ran(done.returncode, done.stdout + done.stderr)

    def stop(self) -> list[tuple[Command, Ran]]:
        """Stop the block's background commands (SIGINT) and give what each printed."""
        stopped = []
        for command, process, log in self.background:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGINT)
            try:
                process.wait(BACKGROUND_STOP_S)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
            stopped.append((command, Ran(process.returncode, log.read_text(encoding='utf-8', errors='replace'))))
        self.background = []
        return stopped

    def _tak_calib(self, words: list[str]) -> Ran:
        """``tak_calib`` in this process (no interpreter start per command): its status and output."""
        from tak_thermo_ros import cli
        buffer = io.StringIO()
        previous = os.getcwd()
        keys = ('COLUMNS', 'ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_HOME', 'ROS_LOG_DIR')
        saved = {key: os.environ.get(key) for key in keys}
        os.environ.update({key: self.env[key] for key in keys})
        try:
            os.chdir(self.directory)
            with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
                try:
                    status = cli.main(words)
                except SystemExit as stop:  # argparse: --help (0) or a usage error (2)
                    status = stop.code if isinstance(stop.code, int) else 1
        finally:
            os.chdir(previous)
            for key, value in saved.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
        return Ran(int(status or 0), buffer.getvalue())


def _in_process(text: str) -> list[str] | None:
    """The arguments of a plain ``tak_calib`` command (no shell needed), else ``None``."""
    command = text.split(' #', 1)[0].strip()
    if SHELL.search(command):
        return None
    words = shlex.split(command)
    return words[1:] if words and words[0] == 'tak_calib' else None


def long_lines(command: Command, output: str) -> list[str]:
    """A ``tak_calib`` command's printed lines longer than :data:`MAX_LINE`."""
    if command.background:
        return []
    return [f'printed a line of {len(line)} characters (at most {MAX_LINE}): {line[:60]!r}...'
            for line in output.splitlines() if len(line) > MAX_LINE and not line.startswith(ERROR)]


def run_doc(path: Path, *, slow: bool, directory: Path, domain: int = 77) -> Iterator[tuple[Block, Command, Ran]]:
    """Run a doc's transcripts in order (``slow``: the slow blocks too); yield each command's outcome."""
    session = Session(directory, domain=domain)
    for block in parse(path):
        if block.slow and not slow:
            continue
        try:
            for command in block.commands:
                ran = session.run(command)
                if ran is not None:
                    yield block, command, ran
        finally:
            for command, ran in session.stop():
                yield block, command, ran


def overwritten(path: Path) -> list[str]:
    """The ``tak_calib`` commands of a doc that write an output an earlier one wrote, without ``--force``.

    Every block in order, the slow ones too, as a reader runs the page in one directory: the second
    command stops at ``exists already, not overwriting`` (unless the doc shows it failing). Each
    command's outputs are the ones the tool itself checks (``tak_thermo_ros.cli.tak_calib.OUTPUTS``;
    ``-o`` of a command that checks its own), read by the tool's own parser.
    """
    from tak_thermo_ros.cli.tak_calib import OUTPUTS, build_parser
    parser = build_parser()
    written: dict[str, Command] = {}
    found = []
    for block in parse(path):
        for command in block.commands:
            words = _in_process(command.text)
            if words is None or command.exit_status:
                continue
            try:
                with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                    args = parser.parse_args(words)
            except SystemExit:  # --help, or a usage the doc shows failing
                continue
            names = [name for name, _, _ in OUTPUTS.get(args.command, ())] or ['output']
            for name in names:
                value = getattr(args, name, None)
                if value is None:
                    continue
                key = os.path.normpath(str(value))
                if key in written and not getattr(args, 'force', False):
                    found.append(f'{_where(block, command)}\n  writes {value} again without --force (line '
                                 f'{written[key].index + 1} wrote it): a reader stops at "exists already"')
                written[key] = command
    return found


def _where(block: Block, command: Command) -> str:
    path = block.path.relative_to(ROOT) if block.path.is_relative_to(ROOT) else block.path
    return f'{path}:{command.index + 1}: $ {command.text}'


def problems_of(block: Block, command: Command, ran: Ran) -> list[str]:
    """Everything in which a command's outcome disagrees with its doc."""
    where = _where(block, command)
    found = []
    if not command.background and ran.status != command.exit_status:
        tail = '\n'.join(ran.output.splitlines()[-5:])
        found.append(f'exit status {ran.status}, the doc says {command.exit_status}:\n{tail}')
    found += compare(command, ran.output, block.tolerance)
    if command.text.split()[0] in LINE_CHECKED:
        found += long_lines(command, ran.output)
    return [f'{where}\n  {problem}' for problem in found]


def check(path: Path, *, slow: bool, directory: Path, domain: int = 77) -> list[str]:
    """Every disagreement between a doc and the tool (empty: the doc is true)."""
    found = []
    for block, command, ran in run_doc(path, slow=slow, directory=directory, domain=domain):
        found += problems_of(block, command, ran)
    return found


def regenerate(path: Path, *, full: bool = False, directory: Path) -> list[str]:
    """Run every block of a doc and write the numbers printed now into it; what could not be matched."""
    lines = path.read_text(encoding='utf-8').splitlines()
    problems = []
    replaced: dict[int, tuple[int, list[str]]] = {}
    for block, command, ran in run_doc(path, slow=True, directory=directory):
        where = _where(block, command)
        if not command.background and ran.status != command.exit_status:
            problems.append(f'{where}\n  exit status {ran.status}, the doc says {command.exit_status}:\n{ran.output}')
        if command.text.split()[0] in LINE_CHECKED:
            problems += [f'{where}\n  {p}' for p in long_lines(command, ran.output)]
        if full:
            first = command.last_index + 1
            last = command.shown[-1].index + 1 if command.shown else first
            output = ran.output.rstrip('\n').splitlines()
            if command.exit_status:
                output.append(f'[{command.exit_status}]')
            replaced[first] = (last, output)
        else:
            problems += [f'{where}\n  {p}' for p in updated(command, ran.output, lines)]
    for first in sorted(replaced, reverse=True):
        last, output = replaced[first]
        lines[first:last] = output
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    return problems


def main(argv: list[str] | None = None) -> int:
    """Regenerate (or ``--check``) the transcripts of the docs given, or of all of them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('docs', nargs='*', type=Path, help='Markdown files (default: README.md and docs/*.md)')
    parser.add_argument('--check', action='store_true', help='compare only, slow blocks included; write nothing')
    parser.add_argument('--full', action='store_true',
                        help="replace each command's shown lines by everything it prints")
    args = parser.parse_args(argv)
    paths = [path.resolve() for path in args.docs] or list(DOCS)
    problems = []
    for path in paths:
        if not parse(path):
            continue
        print(f'{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path} ...', flush=True)
        with tempfile.TemporaryDirectory(prefix='tak-docs-') as directory:
            if args.check:
                problems += check(path, slow=True, directory=Path(directory))
            else:
                problems += regenerate(path, full=args.full, directory=Path(directory))
    for problem in problems:
        print(problem, file=sys.stderr)
    return 1 if problems else 0


if __name__ == '__main__':
    sys.exit(main())
