"""Docs that cannot drift: the ``console`` transcripts of the README and docs/ are run and compared.

The convention and the runner are in ``docs/regenerate.py`` (which also regenerates the long
transcripts). Here: every doc's fast blocks run, in a temporary directory per doc, and must show
what the tool prints (numbers within their tolerance, no ``tak_calib`` line over 100
characters); and the comparison itself must fail when a doc and the tool disagree.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import sys
from pathlib import Path

import pytest

from node_helpers import domain_id
from paths import REPO

ROOT = REPO
_SPEC = importlib.util.spec_from_file_location('regenerate', ROOT / 'docs' / 'regenerate.py')
transcripts = importlib.util.module_from_spec(_SPEC)
sys.modules['regenerate'] = transcripts
_SPEC.loader.exec_module(transcripts)

SLOW = os.environ.get('TAK_DOCS_SLOW') == '1'
"""``TAK_DOCS_SLOW=1``: the slow blocks run too (minutes; ``docs/regenerate.py --check`` does the same)."""
DOCS = [path for path in transcripts.DOCS if any(SLOW or not block.slow for block in transcripts.parse(path))]


@pytest.mark.parametrize('path', DOCS, ids=[path.name for path in DOCS])
def test_the_doc_shows_what_the_tool_prints(path, tmp_path):
    """Every command of the doc's fast blocks succeeds and prints the lines the doc shows.

    One page at a time, its commands in order in one directory, as a reader runs them.
    """
    problems = transcripts.check(path, slow=SLOW, directory=tmp_path, domain=domain_id(41))
    assert not problems, '\n\n'.join(problems)


@pytest.mark.parametrize('path', transcripts.DOCS, ids=[path.name for path in transcripts.DOCS])
def test_no_command_of_a_page_writes_over_what_an_earlier_one_wrote(path):
    """Issue 43: docs/everyday.md's second ``fit lagged -o lagged.yaml`` stopped a reader at "exists already".

    Slow blocks included (the test does not run them): the page read top to bottom in one directory.
    """
    problems = transcripts.overwritten(path)
    assert not problems, '\n\n'.join(problems)


def test_the_overwrite_check_catches_a_second_output_and_lets_force_pass(tmp_path):
    """Two commands writing one file: caught across blocks, a slow one too; ``--force`` or a shown failure is fine."""
    first = '$ tak_calib fit cal -o p.yaml\n'
    path = tmp_path / 'doc.md'
    for second, caught in (('$ tak_calib fit cal -o p.yaml --gyro-effects thermal_lag\n', True),
                           ('$ tak_calib fit cal -o ./p.yaml\n', True),
                           ('$ tak_calib fit cal -o p.yaml --force\n', False),
                           ('$ tak_calib fit cal -o p.yaml\ntak_calib: error: exists already\n[2]\n', False),
                           ('$ tak_calib fit cal -o q.yaml\n', False)):
        path.write_text(f'```console\n{first}```\n\nWords.\n\n```console slow\n{second}```\n', encoding='utf-8')
        assert bool(transcripts.overwritten(path)) is caught, second


def test_every_doc_with_commands_and_output_uses_the_console_convention():
    """A shown ``$ tak_calib`` line with output below it sits in a ``console`` block, where it is run."""
    for path in transcripts.DOCS:
        info = None  # the info string of the block we are in, None outside blocks
        for number, line in enumerate(path.read_text(encoding='utf-8').splitlines(), start=1):
            stripped = line.strip()
            if stripped.startswith('```'):
                info = stripped[3:].strip() if info is None else None
            elif info is not None and not info.startswith('console') and stripped.startswith('$ tak_calib'):
                pytest.fail(f'{path.relative_to(ROOT)}:{number}: a $ command outside a console block: {stripped}')


def _doc(tmp_path: Path, body: str, info: str = 'console') -> Path:
    path = tmp_path / 'doc.md'
    path.write_text(f'Some words.\n\n```{info}\n{body}```\n', encoding='utf-8')
    return path


def _check(tmp_path: Path, body: str, info: str = 'console') -> list[str]:
    work = tmp_path / 'work'
    work.mkdir(exist_ok=True)
    return transcripts.check(_doc(tmp_path, body, info), slow=False, directory=work, domain=domain_id(42))


@pytest.mark.parametrize('body', [
    "$ printf 'x: 1.234 m/s^2\\nwrote it\\n'\nx: 1.234 m/s^2\n",                  # exactly
    "$ printf 'x: 1.234 m/s^2\\nwrote it\\n'\nx: 1.23 m/s^2\nwrote it\n",          # within a unit of 1.23's last digit
    "$ printf 'a\\nb\\nc\\n'\na\nc\n",                                             # a selection, in order
    "$ printf 'a 0.0795   noise model: 0.0801\\n'\na ...   noise model: 0.08\n",   # ... elides
    "$ printf 'took 17 s\\n'\ntook ... s\n",
    "$ printf 'took 17 s\\n'\ntook 20 s [~20%]\n",                                  # a line's own tolerance
    "$ printf 'error\\n'; exit 2\nerror\n[2]\n",                                    # the exit status it must give
    "$ printf 'run2: 6031 Imu\\n'\nrun2: 6031 Imu\n",                              # run2 is a name, not a number
    "$ printf 'range 5.68..34.18 C\\n'\nrange 5.68..34.18 C\n",
])
def test_a_transcript_that_agrees_passes(tmp_path, body):
    assert _check(tmp_path, body) == []


@pytest.mark.parametrize('body, why', [
    ("$ printf 'share -2%%\\n'\nshare -19%\n", 'other numbers'),  # issue 26: -19 % shown, -2 % printed
    ("$ printf 'noise model: 0.0801\\n'\nnoise model: 130\n", 'other numbers'),
    ("$ printf 'x: 1.234\\n'\nx: 1.25\n", 'other numbers'),                         # two units off
    ("$ printf 'a\\nb\\n'\nb\na\n", 'in this order'),                               # order matters
    ("$ printf 'a\\n'\nb\n", 'is not printed'),
    ("$ false\n", 'exit status 1'),                                                # a command must succeed
    ("$ printf 'x\\n'\nx\n[2]\n", 'exit status 0, the doc says 2'),
    ("$ printf 'took 30 s\\n'\ntook 20 s [~20%]\n", 'other numbers'),
])
def test_a_transcript_that_disagrees_fails(tmp_path, body, why):
    problems = _check(tmp_path, body)
    assert problems and why in problems[0], problems


def test_a_block_tolerance_and_slow_blocks(tmp_path):
    """``tolerance=10%`` widens a block's numbers; ``slow`` blocks are skipped by the test, run by the script."""
    assert _check(tmp_path, "$ printf 'rms 1.09\\n'\nrms 1.00\n", 'console tolerance=10%') == []
    assert _check(tmp_path, "$ printf 'rms 1.2\\n'\nrms 1.00\n", 'console tolerance=10%') != []
    assert _check(tmp_path, '$ false\n', 'console slow') == []
    work = tmp_path / 'slow'
    work.mkdir()
    assert transcripts.check(_doc(tmp_path, '$ false\n', 'console slow'), slow=True, directory=work)


def test_a_tak_calib_line_over_100_characters_fails(tmp_path):
    """The rule of issue 26 holds whatever the command: a long line, not an error, is a problem."""
    command = transcripts.Command(index=0, last_index=0, text='tak_calib fit x')
    assert transcripts.long_lines(command, 'x' * 101 + '\nshort\n')
    assert not transcripts.long_lines(command, 'tak_calib: error: ' + 'x' * 120 + '\n')


def test_regenerating_writes_the_printed_numbers_and_keeps_the_words(tmp_path):
    """``docs/regenerate.py`` brings a doc's numbers up to date; its selection, ``...`` and markers stay."""
    path = _doc(tmp_path, "$ printf 'a\\nrms 0.0212 m/s^2 (2.16 mg)\\ntook 17 s\\n'\n"
                          "rms 0.03 m/s^2 (3 mg)\ntook ... s\n")
    work = tmp_path / 'work'
    work.mkdir()
    assert transcripts.regenerate(path, directory=work) == []
    text = path.read_text(encoding='utf-8')
    assert 'rms 0.0212 m/s^2 (2.16 mg)\ntook ... s\n' in text and '\na\n' not in text
    missing = _doc(tmp_path, "$ printf 'b\\n'\na\n")
    assert transcripts.regenerate(missing, directory=work)  # words no longer printed: said, for a person to edit


# ----- docs/cli.md's synopses against the parser ---------------------------------------------------------------

CLI_DOC = ROOT / 'docs' / 'cli.md'
OPTION = re.compile(r'(?<![\w-])(--?[a-zA-Z][\w-]*)')
PLACEHOLDER = re.compile(r'\[([a-z][a-z ]*)\]')
SAID_FOR_EVERY_COMMAND = ('--help', '--debug', '--verbose', '--instance', '--no-progress', '--force')
"""Options docs/cli.md states once for every command (the first line, and the words below the block)."""


def _synopses() -> tuple[dict[str, str], dict[str, str]]:
    """docs/cli.md's first block: each command's synopsis (its lines joined), and the named groups (``stages``)."""
    lines = CLI_DOC.read_text(encoding='utf-8').splitlines()
    start = lines.index('```') + 1
    block = lines[start:lines.index('```', start)]
    commands: dict[str, str] = {}
    groups: dict[str, str] = {}
    current: tuple[dict[str, str], str] | None = None
    for line in block:
        group = re.match(r'^\s+([a-z][a-z ]*):\s', line)
        if line.startswith('tak_calib '):
            word = line.split()[1]
            current = (commands, '' if word.startswith('[') else word)
            commands[current[1]] = line
        elif group:
            current = (groups, group.group(1))
            groups[current[1]] = line[group.end():]
        elif line.startswith(' ') and current is not None:
            current[0][current[1]] += ' ' + line.strip()
        else:
            current = None
    return commands, groups


def _parsers() -> dict[str, argparse.ArgumentParser]:
    from tak_thermo_ros.cli.tak_calib import build_parser
    parser = build_parser()
    return next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction)).choices


def _shown(text: str, groups: dict[str, str], parsers: dict[str, argparse.ArgumentParser]) -> tuple[set[str], set[str]]:
    """The options a synopsis shows, its named groups (``[stages]``) expanded; and those another's stand for.

    ``[fit options]``: the options of ``fit`` that the command has too (a command takes them, not all of them).
    """
    shown, borrowed = set(OPTION.findall(text)), set()
    for name in PLACEHOLDER.findall(text):
        if name in groups:
            shown |= set(OPTION.findall(groups[name]))
        elif name.endswith(' options') and name.removesuffix(' options') in parsers:
            borrowed |= {o for a in parsers[name.removesuffix(' options')]._actions for o in a.option_strings}
    return shown, borrowed


def test_every_cli_md_synopsis_shows_the_parsers_options_and_no_other():
    """Issue 43: the synopses lacked ``diagnose --settle-time``, ``import-csv --frame-id --storage``, ...

    Each command of ``tak_calib`` has a synopsis in docs/cli.md; every option it shows is the
    command's; every option the command has is shown, but for those said once for all (the first
    line's, ``--instance``) and the topic options (said below the block).
    """
    commands, groups = _synopses()
    parsers = _parsers()
    assert set(commands) - {''} == set(parsers), 'commands without a synopsis, or synopses without a command'
    text = CLI_DOC.read_text(encoding='utf-8')
    assert all(f'`{option}' in text or option in commands[''] for option in SAID_FOR_EVERY_COMMAND)
    common = set(OPTION.findall(commands[''])) | set(SAID_FOR_EVERY_COMMAND)
    problems = []
    for name, parser in parsers.items():
        shown, borrowed = _shown(commands[name], groups, parsers)
        known = {option for action in parser._actions for option in action.option_strings}
        if shown - known - common:
            problems.append(f'{name}: the synopsis shows what the command does not have: {sorted(shown - known)}')
        for action in parser._actions:
            options = set(action.option_strings)
            if options and not options & (shown | borrowed | common) and not action.dest.endswith('_topic'):
                problems.append(f'{name}: {"/".join(action.option_strings)} is not in its synopsis')
    assert not problems, '\n'.join(problems)


def test_the_synopsis_check_fails_on_a_missing_and_an_unknown_option(monkeypatch, tmp_path):
    """The check itself: a synopsis without ``--seed`` and one with ``--colour`` are both caught."""
    text = CLI_DOC.read_text(encoding='utf-8')
    for changed in (text.replace('[--seed N] [--storage', '[--storage', 1),
                    text.replace('[--seed N] [--storage', '[--seed N] [--colour C] [--storage', 1)):
        assert changed != text
        doc = tmp_path / 'cli.md'
        doc.write_text(changed, encoding='utf-8')
        monkeypatch.setattr(sys.modules[__name__], 'CLI_DOC', doc)
        with pytest.raises(AssertionError, match='simulate: '):
            test_every_cli_md_synopsis_shows_the_parsers_options_and_no_other()


def test_the_architecture_diagram_names_every_pass():
    """docs/architecture.md's ``passes/`` lists every module of the package's passes (issue 43: pool, watch)."""
    text = (ROOT / 'docs' / 'architecture.md').read_text(encoding='utf-8')
    listed = re.search(r'passes/[^\n]*one module per pass: (.*?)\n\d', text, flags=re.DOTALL).group(1)
    names = set(re.findall(r'[a-z_]+', listed.replace('|', ' ')))
    modules = {path.stem for path in (ROOT / 'tak_thermo_ros' / 'passes').glob('*.py') if path.stem != '__init__'}
    assert modules <= names, f'passes not in the diagram: {sorted(modules - names)}'


# ----- every relative link resolves ----------------------------------------------------------------------------

LINK = re.compile(r'!?\[[^\]]*\]\(([^)\s]+)\)')


def _anchors(path: Path) -> set[str]:
    """The anchors GitHub makes of a Markdown file's headings (lower case, punctuation dropped, spaces as -)."""
    anchors: set[str] = set()
    fenced = False
    for line in path.read_text(encoding='utf-8').splitlines():
        if line.strip().startswith(('```', '~~~')):
            fenced = not fenced
        heading = None if fenced else re.match(r'^#{1,6}\s+(.*?)\s*#*\s*$', line)
        if heading:
            slug = re.sub(r'[^\w\- ]', '', heading.group(1).lower()).replace(' ', '-')
            anchor, n = slug, 0
            while anchor in anchors:
                n += 1
                anchor = f'{slug}-{n}'
            anchors.add(anchor)
    return anchors


def broken_links(path: Path) -> list[str]:
    """The relative links of a Markdown file (outside code) whose file or heading does not exist."""
    problems = []
    fenced = False
    name = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    for number, line in enumerate(path.read_text(encoding='utf-8').splitlines(), start=1):
        if line.strip().startswith(('```', '~~~')):
            fenced = not fenced
            continue
        if fenced:
            continue
        for target in LINK.findall(re.sub(r'`[^`]*`', '', line)):
            if re.match(r'^[a-z]+:', target):  # https:, mailto:
                continue
            file, _, anchor = target.partition('#')
            resolved = (path.parent / file).resolve() if file else path
            if not resolved.exists():
                problems.append(f'{name}:{number}: {target}: no such file')
            elif anchor and resolved.suffix == '.md' and anchor not in _anchors(resolved):
                problems.append(f'{name}:{number}: {target}: no such heading')
    return problems


@pytest.mark.parametrize('path', transcripts.DOCS, ids=[path.name for path in transcripts.DOCS])
def test_every_relative_link_resolves(path):
    """Every relative link of README.md and docs/*.md names a file that exists, and a heading it holds."""
    problems = broken_links(path)
    assert not problems, '\n'.join(problems)


def test_the_link_check_catches_a_missing_file_and_heading(tmp_path):
    """The check itself: a link to no file, and to a heading the file lacks, are caught; good ones are not."""
    doc = tmp_path / 'doc.md'
    (tmp_path / 'other.md').write_text('# Other\n\n## The Earth\'s field: `fit-fleet` (and thermal_lag[xz])\n')
    doc.write_text('[a](other.md) [b](other.md#the-earths-field-fit-fleet-and-thermal_lagxz) [c](#top)\n\n# Top\n'
                   '`[not a link](nowhere.md)`\n```\n[in code](nowhere.md)\n```\n', encoding='utf-8')
    assert broken_links(doc) == []
    doc.write_text('[a](missing.md) [b](other.md#nothing) [c](#gone)\n', encoding='utf-8')
    assert len(broken_links(doc)) == 3
