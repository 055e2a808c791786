"""Source explains the code, not its history: no issue number (``issue 31``, ``#33``,
``PR 12``) and no commit hash in the Python files of ``safe_bc/``, ``tune_jobs/``,
``scripts/``, ``benchmarks/`` and ``tests/``. That history lives in ``docs/history.md`` and
the commit messages.

The only exceptions are data: strings written into committed result tables or reports, and
example ids in the shape of a hash (:data:`ALLOWED`, each with its file); this file's own
examples of what the check catches are not read."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FOLDERS = ("safe_bc", "tune_jobs", "scripts", "benchmarks", "tests")

ISSUE = re.compile(r"\b[Ii]ssues?[ -]#?\d+|(?<![\w&#])#\d{2,}\b|\bPR ?#?\d+\b")
"""``issue 31``, ``Issues 31 and 35``, ``issue-31``, ``#33``, ``PR 12`` (not ``# 2`` or a
colour such as ``#1f77b4``)."""
HASH = re.compile(r"(?<![\w:./-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{7,40}(?!\w)")
"""7 to 40 lower-case hex digits, with at least one letter and one digit, as a word of its
own (not a ``sha256:...`` digest, a path or part of a longer word)."""

ALLOWED: dict[str, set[str]] = {
    # the heading of results/queries/*/summary.md
    # the heading of results/selfimprove/carracing/defer_designs.md
    "scripts/defer_designs.py": {"issue 35"},
    # notes of make bench's rows in results/bench.parquet
    "benchmarks/cases/env.py": {"issue 33"},
    # example trial ids in a doctest, an example agent digest in a test
    "safe_bc/study/final.py": {"3f2a9c01", "77aa0b12"},
    "tests/scripts/test_study_rerun.py": {"ab12cd34"},
}
"""File -> the matches it may hold (data, listed in ``docs/history.md``)."""


def history_in(text: str) -> list[tuple[int, str]]:
    """``(line, match)`` of every issue number or commit hash in ``text``.

    >>> history_in("see issue 31\\n# 2 rows; #33 and commit 1ce2cf8\\nsha256:64e8ca59a1")
    [(1, 'issue 31'), (2, '#33'), (2, '1ce2cf8')]
    >>> history_in("color='#1f77b4', seed 1075841861, cafebabe, data/run_0a")
    []
    """
    out = []
    for i, line in enumerate(text.splitlines(), 1):
        found = [*ISSUE.finditer(line), *HASH.finditer(line)]
        out += [(i, m.group(0)) for m in sorted(found, key=lambda m: m.start())]
    return out


def test_no_issue_numbers_or_commit_hashes_in_source():
    found = []
    for folder in FOLDERS:
        for path in sorted((REPO / folder).rglob("*.py")):
            if path.resolve() == Path(__file__).resolve():
                continue
            name = path.relative_to(REPO).as_posix()
            allowed = ALLOWED.get(name, set())
            found += [
                f"{name}:{line}: {match!r}"
                for line, match in history_in(path.read_text())
                if match not in allowed
            ]
    assert not found, "history belongs in docs/history.md or a commit message:\n" + "\n".join(found)


def test_every_allowed_match_is_still_there():
    """An exception whose string went away leaves :data:`ALLOWED` (the list only shrinks)."""
    stale = []
    for name, allowed in ALLOWED.items():
        present = {match for _, match in history_in((REPO / name).read_text())}
        stale += [f"{name}: {a!r}" for a in sorted(allowed - present)]
    assert not stale, stale
