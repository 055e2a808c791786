"""Running a study's replicates (``safe-bc tune STUDY --replicates N``): replicate ``k`` is the
study with its seeds shifted (:func:`safe_bc.study.replicates.replicate_spec`), run as a normal,
resumable study in ``<results>/<study>/replicates/r<k>/``, one after the other (each study
already uses every CPU). A replicate whose final phase is written for the same settings is
skipped; an interrupted one resumes. Once all are done, ``<results>/<study>/replicates.parquet``
and ``replicates.md`` hold the table of the winners
(:func:`safe_bc.study.replicates.replicate_table`),
built from what each final phase wrote (nothing is evaluated again).
"""

from __future__ import annotations

import json
import shlex
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.locks import output_locks
from safe_bc.data.provenance import check_result_write, provenance
from safe_bc.data.store import read_table, read_table_metadata, write_table_atomic
from safe_bc.study.plan import experiment_location
from safe_bc.study.replicates import (
    REPLICATE_STRIDE,
    REPLICATES,
    ReplicateResult,
    replicate_seeds,
    replicate_spec,
    replicate_table,
    replicates_markdown,
    replicates_summary,
)
from safe_bc.study.run import format_outcome, run_study
from safe_bc.study.spec import StudySpec
from safe_bc.study.trial import TrialJob, run_trial

TABLE = f"{REPLICATES}.parquet"
"""The replicate table, in the study's folder."""
REPORT = f"{REPLICATES}.md"
"""Its Markdown rendering, beside it."""


@dataclass(frozen=True)
class ReplicatesOutcome:
    """What :func:`run_replicates` did."""

    complete: bool
    """Every replicate finished (else a rerun resumes the interrupted one)."""
    ran: tuple[int, ...]
    """The replicates run (or resumed) by this call; the others were finished before."""
    table: pd.DataFrame | None
    """The replicate table (``None`` while incomplete)."""
    summary: dict[str, Any] | None
    """Its summary and verdict (``None`` while incomplete)."""
    out: Path
    """The study's folder, holding ``replicates.parquet``, ``replicates.md`` and
    ``replicates/r<k>/``."""
    errors: int
    """Trials that failed after all retries, over the replicates run by this call."""


def _as_stored(value: Any) -> Any:
    """``value`` as a table's JSON metadata stores it (tuples become lists, paths text)."""
    return json.loads(json.dumps(value, sort_keys=True, default=str))


def finished(spec: StudySpec) -> bool:
    """Whether the study ``spec`` (a replicate) has its final phase written for exactly these
    settings: ``final.parquet`` records a complete study with this summary (a field the
    recorded summary lacks, added to ``StudySpec`` since, is not compared: as a resume compares
    identities, :func:`safe_bc.study.resume.identity_problem`), and ``best.json``
    (written last) is there."""
    from safe_bc.study.resume import identity_problem

    folder = spec.results / spec.name
    if not ((folder / "final.parquet").is_file() and (folder / "best.json").is_file()):
        return False
    meta = read_table_metadata(folder / "final.parquet")
    stored = meta.get("study")
    return (
        meta.get("complete") is True
        and isinstance(stored, dict)
        and not identity_problem(stored, _as_stored(spec.summary()))
    )


def read_replicate(spec: StudySpec, k: int) -> ReplicateResult:
    """What replicate ``k``'s final phase wrote (no winner when it wrote none)."""
    folder = spec.results / spec.name
    seeds = replicate_seeds(spec)
    if not (folder / "final.parquet").is_file():
        empty = pd.DataFrame()
        return ReplicateResult(k, seeds, None, False, {}, empty, empty)
    final, meta = read_table(folder / "final.parquet")
    paired_path = folder / "final_paired.parquet"
    paired = read_table(paired_path)[0] if paired_path.is_file() else pd.DataFrame()
    best_path = folder / "best.json"
    best = json.loads(best_path.read_text()) if best_path.is_file() else {}
    cert_path = folder / "certify.parquet"
    certificate = read_table_metadata(cert_path).get("certificate") if cert_path.is_file() else None
    return ReplicateResult(
        k,
        seeds,
        meta.get("winner"),
        bool(meta.get("winner_feasible")),
        dict(best.get("params") or {}),
        final,
        paired,
        certificate,
    )


def _source(spec: StudySpec) -> dict[str, Any]:
    """Where replicate ``spec``'s numbers come from: its final table's command, provenance,
    seeds and inputs (the demonstrations' digest and collector settings)."""
    path = spec.results / spec.name / "final.parquet"
    meta = read_table_metadata(path) if path.is_file() else {}
    return {
        "folder": str(spec.results / spec.name),
        "command": meta.get("command", ""),
        "seeds": replicate_seeds(spec),
        "provenance": meta.get("provenance", {}),
        "inputs": meta.get("inputs", {}),
    }


def run_replicates(
    spec: StudySpec,
    n: int,
    *,
    fresh: bool = False,
    command: str = "",
    progress: bool = True,
    trial_fn: Callable[[dict[str, Any], TrialJob], None] = run_trial,
) -> ReplicatesOutcome:
    """Run (or resume) ``n`` replicates of ``spec`` one after the other, then write
    ``replicates.parquet`` and ``replicates.md`` in ``<results>/<study>/``.

    Args:
        fresh: start every replicate over (its Tune experiment and outputs are deleted).
        command: the command line, recorded in every table.
        progress: Tune's console progress.
        trial_fn: the per-trial function (tests wrap it).

    Raises:
        ValueError: ``n < 1``, or a study whose seeds cannot be shifted
            (:func:`safe_bc.study.replicates.replicate_spec`).
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"--replicates must be an integer >= 1, got {n!r}")
    out = spec.results / spec.name
    check_result_write(out / TABLE)  # a dirty tree fails now, not after the studies
    specs = [replicate_spec(spec, k) for k in range(n)]  # bad seeds fail before any work
    if fresh:
        for name in (TABLE, REPORT):
            (out / name).unlink(missing_ok=True)
    ran, errors = [], 0
    for k, rspec in enumerate(specs):
        folder = rspec.results / rspec.name
        if not fresh and finished(rspec):
            print(f"replicate {k}/{n}: finished before ({folder}), skipped")
            continue
        seeds = replicate_seeds(rspec)
        print(f"replicate {k}/{n}: {folder} ({', '.join(f'{a} {b}' for a, b in seeds.items())})")
        outcome = run_study(rspec, fresh=fresh, command=command, progress=progress,
                            trial_fn=trial_fn)  # fmt: skip
        ran.append(k)
        errors += outcome.errors
        if progress:
            print(format_outcome(outcome, rspec.params))
        if not outcome.complete:
            return ReplicatesOutcome(False, tuple(ran), None, None, out, errors)
    results = [read_replicate(rspec, k) for k, rspec in enumerate(specs)]
    table = replicate_table(results, spec.params)
    summary = replicates_summary(table)
    sources = {rspec.name: _source(rspec) for rspec in specs}
    prov = provenance()
    meta = {
        "command": command,
        "study": spec.summary(),
        "replicates": n,
        "replicate_stride": REPLICATE_STRIDE,
        "summary": summary,
        "sources": sources,
        "inputs": replicate_inputs(sources),
        "provenance": prov,
    }
    write_table_atomic(out / TABLE, table, meta)
    write_text_atomic(out / REPORT, replicates_markdown(table, summary, spec.params, _note(
        command, sources)))  # fmt: skip
    return ReplicatesOutcome(True, tuple(ran), table, summary, out, errors)


def replicate_inputs(sources: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The demonstration sets the replicates read (``{"demos": [record, ...]}``, one record per
    digest; a replicate whose tables record none counts as ``{"digest": None}``)."""
    sets: dict[Any, dict[str, Any]] = {}
    for src in sources.values():
        record = dict(src.get("inputs", {}).get("demos") or {"digest": None})
        sets.setdefault(record.get("digest"), record)
    return {"demos": list(sets.values())}


def _note(command: str, sources: dict[str, dict[str, Any]]) -> str:
    """The report's closing lines: the command, and each replicate's revision and machine."""
    lines = [f"Made by `{command}`." if command else "", ""]
    rows = []
    for name, src in sources.items():
        p = src.get("provenance", {})
        rows.append(
            {
                "replicate": name,
                "revision": str(p.get("git_revision", ""))[:12],
                "CPU": p.get("cpu_model", "not recorded"),
                "torch kernels": p.get("torch_cpu_capability", "not recorded"),
                "torch": p.get("torch_version", "not recorded"),
            }
        )
    lines.append("Where each replicate's final phase ran:")
    lines += ["", pd.DataFrame(rows).to_markdown(index=False)]
    return "\n".join(lines).lstrip("\n")


def replicate_outputs(spec: StudySpec) -> list[tuple[Path, str]]:
    """The folders a replicate run writes, for their locks: the study's results folder and,
    on local storage, the replicates' Tune folder."""
    storage, _ = experiment_location(replicate_spec(spec, 0))
    outputs = [(spec.results / spec.name, "--results")]
    if "://" not in storage:
        outputs.append((Path(storage), "--storage"))
    return outputs


def tune_replicates(spec: StudySpec, n: int, *, fresh: bool, argv: Sequence[str]) -> int:
    """``safe-bc tune STUDY --replicates N``: lock the outputs, run :func:`run_replicates`,
    print the table and the verdict; the exit status (0 done, 1 a replicate without a winner
    or with failed trials, 130 interrupted: rerun to resume)."""
    with output_locks(replicate_outputs(spec)):
        outcome = run_replicates(spec, n, fresh=fresh, command=shlex.join(argv))
    if not outcome.complete or outcome.table is None or outcome.summary is None:
        print(f"replicates incomplete ({len(outcome.ran)} run by this call): run the same "
              "command again to resume")  # fmt: skip
        return 130
    print((outcome.out / REPORT).read_text())
    print(f"wrote {outcome.out / TABLE} and {outcome.out / REPORT}")
    missing = outcome.summary["replicates"] - outcome.summary["with_winner"]
    return 1 if outcome.errors or missing else 0
