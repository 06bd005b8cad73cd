"""The repository's folders, for the tests at any depth of test/ (and the bench scripts that import them).

The tests mirror the package's tree (test/core/fit/, test/formats/, ...): a test finds the repository
here, not by counting its own parents.
"""

from __future__ import annotations

from pathlib import Path

TEST = Path(__file__).resolve().parent
"""test/: conftest.py and the shared helpers (node_helpers.py, everyday_watch.py, ...)."""

REPO = TEST.parent
"""The repository's root."""
