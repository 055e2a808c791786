"""Which demonstration set every committed result table was made from, read off the limits
``d_s`` its metadata records (tables made before digests were recorded name no set): the
committed default sets (``results/demos/summary.json`` for CarRacing; the rehab task's default
collection) or another one. Writes ``results/checks/input_sets.md`` (``python -m
scripts.input_sets``); a test checks that the committed file is current."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import pyarrow.parquet as pq

from safe_bc.report import markdown_table

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results" / "checks" / "input_sets.md"
REHAB_LIMITS = (0.77, 0.8, 2.14)
"""d_s of the rehab task's default collection (150 guideline programmes), rounded to 0.01."""


def recorded_limits(path: Path) -> tuple[float, ...] | None:
    """The ``d_s`` a result table's metadata records (``cost_limits``, ``limits`` or
    ``thresholds``), rounded to 0.01; ``None`` when it records none."""
    raw = (pq.read_metadata(path).metadata or {}).get(b"safe_bc")
    if not raw:
        return None
    meta = json.loads(raw)
    for key in ("cost_limits", "limits", "thresholds"):
        value = meta.get(key)
        if isinstance(value, list) and value and all(isinstance(x, int | float) for x in value):
            return tuple(round(float(x), 2) for x in value)
    return None


def set_names() -> dict[tuple[float, ...], str]:
    """Known limits -> the name of their demonstration set."""
    summary = json.loads((ROOT / "results" / "demos" / "summary.json").read_text())
    car = tuple(round(float(v["d_s"]), 2) for v in summary["limits"].values())
    return {
        car: "the committed default CarRacing set (results/demos/summary.json)",
        REHAB_LIMITS: "the rehab task's default set",
    }


def input_sets(root: Path = ROOT) -> str:
    """The Markdown report: one row per (folder two levels under ``results/``, limits)."""
    names = set_names()
    groups: dict[tuple[str, tuple[float, ...]], int] = defaultdict(int)
    for path in sorted((root / "results").rglob("*.parquet")):
        limits = recorded_limits(path)
        if limits is None:
            continue
        parts = path.relative_to(root).parts
        folder = "/".join(parts[: min(3, len(parts) - 1)])  # results/<family>/<table or folder>
        groups[(folder, limits)] += 1
    rows = [
        [folder, ", ".join(f"{x:.2f}" for x in limits), names.get(limits, "another set"), n]
        for (folder, limits), n in sorted(groups.items())
    ]
    table = markdown_table(rows, ["folder", "d_s recorded", "demonstrations", "tables"])
    return (
        "# Which demonstrations each committed table was made from\n\n"
        "Read off the limits d_s each table's metadata records (tables that record none are "
        "not listed). Tables made from another set than the committed default one cannot be "
        "reproduced from a fresh clone, which collects the default set; their figures stand "
        "for the set they name only. Made by `python -m scripts.input_sets`.\n\n" + table + "\n"
    )


def main() -> None:
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(input_sets())
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
