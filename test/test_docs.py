"""Docs that cannot drift: the ``console`` transcripts of the README and docs/ are run and compared.

The convention and the runner are in ``docs/regenerate.py`` (which also regenerates the long
transcripts). Here: every doc's fast blocks run, in a temporary directory per doc, and must show
what the tool prints (numbers within their tolerance, no ``tak_calib`` line over 100
characters); and the comparison itself must fail when a doc and the tool disagree.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from node_helpers import domain_id

ROOT = Path(__file__).resolve().parents[1]
_SPEC = importlib.util.spec_from_file_location('regenerate', ROOT / 'docs' / 'regenerate.py')
transcripts = importlib.util.module_from_spec(_SPEC)
sys.modules['regenerate'] = transcripts
_SPEC.loader.exec_module(transcripts)

DOCS = [path for path in transcripts.DOCS if any(not block.slow for block in transcripts.parse(path))]


@pytest.mark.parametrize('path', DOCS, ids=[path.name for path in DOCS])
def test_the_doc_shows_what_the_tool_prints(path, tmp_path):
    """Every command of the doc's fast blocks succeeds and prints the lines the doc shows."""
    problems = transcripts.check(path, slow=False, directory=tmp_path, domain=domain_id(41))
    assert not problems, '\n\n'.join(problems)


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
