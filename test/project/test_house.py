"""Rooms of readable size: no module over 600 lines without its reason written in its docstring."""

from __future__ import annotations

import ast
from pathlib import Path

from paths import REPO

PACKAGE = REPO / 'tak_thermo_ros'
MOST_LINES = 600
REASON = 'Over 600 lines because'


def _gives_its_reason(path: Path) -> bool:
    """Whether the module docstring holds a paragraph starting with REASON."""
    docstring = ast.get_docstring(ast.parse(path.read_text(encoding='utf-8'))) or ''
    return any(paragraph.strip().startswith(REASON) for paragraph in docstring.split('\n\n'))


def _offenders() -> list[str]:
    """The modules over MOST_LINES lines whose docstring does not say why, with their line counts."""
    offenders = []
    for path in sorted(PACKAGE.rglob('*.py')):
        lines = len(path.read_text(encoding='utf-8').splitlines())
        if lines > MOST_LINES and not _gives_its_reason(path):
            offenders.append((path.relative_to(PACKAGE).as_posix(), lines))
    return offenders


def test_no_module_over_600_lines_without_its_reason():
    """Every module has at most 600 lines, or its docstring says why in a paragraph `Over 600 lines because`."""
    offenders = [f'{name} ({lines} lines)' for name, lines in _offenders()]
    assert not offenders, (f'over {MOST_LINES} lines with no paragraph "{REASON} ..." in the module docstring: '
                           + ', '.join(offenders))
