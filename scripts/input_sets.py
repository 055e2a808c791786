"""Which demonstration set every committed result table was made from, read off the limits
``d_s`` its metadata records, or where it records none, the demonstrations' safety mean
(tables made before digests were recorded name no set): a described CarRacing set
(``results/demos/**/summary.json``: the committed default one, and the exact renderer's
that older tables used), the rehab task's default collection, or another one. Writes
``results/checks/input_sets.md`` (``python -m scripts.input_sets``); a test checks that the
committed file is current."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from safe_bc.report import markdown_table

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results" / "checks" / "input_sets.md"
REHAB_CARD = Path("results/rehab/recommender/recommender.json")
"""The rehab recommender's card: it records the rehab task's default collection (150
guideline programmes, ``safe-bc collect --env rehab``) by digest and limits."""


def rounded_limits(values: Any) -> tuple[float, ...]:
    """``d_s`` per dimension rounded to 0.01: how the ledger matches limits across tables."""
    return tuple(round(float(x), 2) for x in values)


def described_sets(root: Path = ROOT) -> list[tuple[Path, dict[str, Any], tuple[float, ...]]]:
    """Each described CarRacing set: its ``results/demos/**/summary.json``, the summary and its
    limits (:func:`rounded_limits`)."""
    out = []
    for path in sorted((root / "results" / "demos").rglob("summary.json")):
        summary = json.loads(path.read_text())
        out.append((path, summary, rounded_limits(v["d_s"] for v in summary["limits"].values())))
    return out


def rehab_card(root: Path = ROOT) -> dict[str, Any]:
    """The rehab recommender's card (:data:`REHAB_CARD`)."""
    return json.loads((root / REHAB_CARD).read_text())


REHAB_LIMITS = rounded_limits(rehab_card()["limits"].values())
"""d_s of the rehab task's default collection, as its recommender's card records them."""
DEFAULT_LIMITS = next(lim for p, _, lim in described_sets() if p.parent == ROOT / "results/demos")
"""d_s of the committed default CarRacing set (``results/demos/summary.json``)."""
STANDS: dict[str, str] = {
    "results/ablation/renderer": "by design: it compares the exact renderer's pipeline "
    "(its demonstrations among them) with the raster one; the pipeline tables collect both "
    "sets themselves, in a folder named by the code revision that collected them",
    "results/checks/make_tune": "timings of code versions since replaced, each run side by "
    "side with the code of its day (that code collects the exact set), and the half-time "
    "design's replicates of then (`half/one_seed/`); on the committed set: `make tune`'s "
    "timing in `recommender/`, the designs' comparison in `half/replicates.md`",
    "results/default_two_seeds": "the two-seed design's single study of then; the same study "
    "on the committed set is its replicate 0 (`replicates/r0/`)",
}
"""Folders whose tables from another CarRacing set stand as they are, and why; every other
such folder is to be rerun on the committed set."""


def table_meta(path: Path) -> dict[str, Any]:
    """A result table's ``safe_bc`` metadata (``{}``: none), read from its footer."""
    raw = (pq.read_metadata(path).metadata or {}).get(b"safe_bc")
    return json.loads(raw) if raw else {}


def limits_in(meta: dict[str, Any]) -> tuple[float, ...] | None:
    """The ``d_s`` table metadata records (``cost_limits``, ``limits`` or ``thresholds``),
    rounded to 0.01; ``None`` when it records none."""
    for key in ("cost_limits", "limits", "thresholds"):
        value = meta.get(key)
        if isinstance(value, list) and value and all(isinstance(x, int | float) for x in value):
            return rounded_limits(value)
    return None


def recorded_limits(path: Path) -> tuple[float, ...] | None:
    """The ``d_s`` a result table's metadata records (:func:`limits_in`)."""
    return limits_in(table_meta(path))


UNRECORDED = "unrecorded"
"""The ledger's stand-in for the limits of a table that names a demonstrations folder but
records neither its limits nor its content (a table of the ablation script that preceded the
comparison runner)."""


def names_demos_only(path: Path, meta: dict[str, Any] | None = None) -> bool:
    """Whether a result table names the demonstrations it read only by path: its metadata
    (``meta``, read from ``path`` when not given) has ``demos`` but no limits, no
    ``demos_digest`` and no ``inputs`` record. Tables inside an agent's or a run's folder (a
    comparison's ``*runs``, a study's final-phase ``final_*`` folders) are left to that agent's
    record (its ``config.json``) and the table that names the run."""
    parts = path.parts
    if "results" in parts:  # only the folders below results/: not where the checkout lives
        parts = parts[len(parts) - parts[::-1].index("results") :]
    folders = parts[:-1]
    if any(p == "agent" or p.endswith("runs") or p.startswith("final_") for p in folders):
        return False
    meta = table_meta(path) if meta is None else meta
    return "demos" in meta and not ({"demos_digest", "inputs"} & meta.keys())


def safety_mean_in(meta: dict[str, Any]) -> float | None:
    """The demonstrations' safety mean (``demo_safety_mean``, to six digits) table metadata
    records when it records neither limits nor an ``inputs`` record; ``None`` otherwise."""
    mean = meta.get("demo_safety_mean")
    if "inputs" in meta or not isinstance(mean, int | float) or limits_in(meta):
        return None
    return round(float(mean), 6)


def sets_by_safety_mean(root: Path = ROOT) -> dict[float, tuple[float, ...]]:
    """Safety mean (six digits) -> limits of each described CarRacing set (its summary's) and
    of the rehab task's default set where its card is committed (the mean the committed tables
    that name its digest record): a table that records only the mean is placed with its set."""
    means = {
        round(float(summary["safety_mean"]), 6): lim for _, summary, lim in described_sets(root)
    }
    if not (root / REHAB_CARD).is_file():
        return means
    card = rehab_card(root)
    for path in sorted((root / "results").rglob("*.parquet")):
        meta = table_meta(path)
        demos = (meta.get("inputs") or {}).get("demos") or []
        digests = [d.get("digest") if isinstance(d, dict) else d for d in demos]
        mean = meta.get("demo_safety_mean")
        if digests == [card["demos"]["digest"]] and isinstance(mean, int | float):
            means[round(float(mean), 6)] = rounded_limits(card["limits"].values())
    return means


def described_set(limits: Any, root: Path = ROOT) -> dict[str, Any]:
    """The described CarRacing set (``results/demos/**/summary.json``) whose ``d_s`` are
    ``limits`` to 0.01: its digest and summary file, for a table made before digests were
    recorded (``{}``: none matches)."""
    want = rounded_limits(limits or ())
    for path, summary, found in described_sets(root):
        if found == want:
            where = path.relative_to(root).as_posix()
            return {"digest": summary.get("digest"), "identified_by": f"its d_s, as {where}"}
    return {}


def set_names(root: Path = ROOT) -> dict[tuple[float, ...], str]:
    """Known limits -> the name of their demonstration set: each described set
    (``results/demos/**/summary.json``, named by its renderer, the command that collects it
    and its content digest) and the rehab task's default set."""
    names = {REHAB_LIMITS: "the rehab task's default set"}
    for path, summary, limits in described_sets(root):
        renderer = summary["dataset"].get("renderer", "")
        where = path.relative_to(root).as_posix()
        default = path.parent == root / "results" / "demos"
        name = (
            "the committed default CarRacing set" if default else f"the {renderer} renderer's set"
        )
        command = "`make demos`" if default else f"`safe-bc collect --renderer {renderer}`"
        digest = summary.get("digest", "")
        names[limits] = f"{name} ({where}: {command}" + (f", {digest[:15]}...)" if digest else ")")
    return names


def input_sets(root: Path = ROOT) -> str:
    """The Markdown report: one row per (folder two levels under ``results/``, set, what
    identified it)."""
    names, means = set_names(root), sets_by_safety_mean(root)
    groups: dict[tuple[str, tuple[float, ...] | str, str], int] = defaultdict(int)
    for path in sorted((root / "results").rglob("*.parquet")):
        meta = table_meta(path)
        limits: tuple[float, ...] | str | None = limits_in(meta)
        how = "" if limits is None else "d_s " + ", ".join(f"{x:.2f}" for x in limits)
        mean = safety_mean_in(meta)
        if mean is not None:
            limits, how = means.get(mean, UNRECORDED), f"safety mean {mean:.6f} (no d_s)"
        elif limits is None and names_demos_only(path, meta):
            limits, how = UNRECORDED, UNRECORDED
        if limits is None:
            continue
        parts = path.relative_to(root).parts
        folder = "/".join(parts[: min(3, len(parts) - 1)])  # results/<family>/<table or folder>
        groups[(folder, limits, how)] += 1
    rows = [
        [
            folder,
            how,
            "a folder named by path only" if limits == UNRECORDED and how == UNRECORDED
            else names.get(limits, "another set"),
            n,
            _status(folder, limits),
        ]
        for (folder, limits, how), n in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][2]))
    ]  # fmt: skip
    table = markdown_table(rows, ["folder", "recorded", "demonstrations", "tables", "status"])
    return (
        "# Which demonstrations each committed table was made from\n\n"
        "Read off the limits d_s each table's metadata records or, where it records none, the "
        "demonstrations' safety mean it records (to six digits; each described set's differs); "
        "a table that names its demonstrations folder by path alone is `unrecorded`; tables "
        "that read no demonstrations are not listed. A fresh clone collects the committed "
        "default set; a table made from another described set is re-derived after collecting "
        "that set with the command named (the same digest: its content is the same); its "
        "figures stand for that set only. Status: current (the committed sets), stands (why "
        "another set is the right input), or to rerun on the committed set. Made by "
        "`python -m scripts.input_sets`.\n\n" + table + "\n"
    )


def _status(folder: str, limits: tuple[float, ...] | str) -> str:
    """Whether a folder's tables from a set are current: the committed and the rehab sets
    are; another set's stand where :data:`STANDS` says why, else they are to be rerun (so are
    tables whose set is unrecorded)."""
    if limits in (DEFAULT_LIMITS, REHAB_LIMITS):
        return "current"
    if folder in STANDS:
        return f"stands: {STANDS[folder]}"
    if limits == UNRECORDED:
        return "to rerun: its demonstrations are unidentified"
    return "to rerun on the committed set"


def main() -> None:
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(input_sets())
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
