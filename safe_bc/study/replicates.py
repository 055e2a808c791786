"""Replicate studies: the same study run with its seeds moved to other blocks, and the table of
what its winner did in each (pure: no I/O, no Ray).

A study is a random procedure: the sampler's seed, the trials' training seeds and held-out
tracks, the final phase's tracks and training seeds (and, on another CPU, torch's rounding)
decide which trial wins and how it fares on the fresh tracks. One study is one draw; its
verdict ("the winner is below the expert") is a property of that draw. Replicate ``k`` is the
same study with every seed shifted by ``k * REPLICATE_STRIDE`` (:func:`replicate_spec`);
the replicate table (:func:`replicate_table`) holds one row per replicate (the winner's
configuration, its final-phase reward, its paired differences to the expert and to plain BC
with their intervals, its episodes beyond ``d_s``) and a summary whose verdict is what the
replicates support together (:func:`replicates_verdict`).

The demonstrations are the same in every replicate: the spread is the procedure's given the
data, not over data sets. The Ray side is :mod:`safe_bc.study.run_replicates`.

>>> from safe_bc.study.spec import Float
>>> spec = StudySpec("demo", {"selection.alpha": Float(0.0, 1.0)})
>>> r = replicate_spec(spec, 2)
>>> r.name, str(r.results), r.sampler_seed, r.base.bc.train.seed, r.eval_seed, r.final_seed
('r2', 'results/demo/replicates', 200, 200, 201, 202)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.seeds import heldout_seed
from safe_bc.study.spec import StudySpec

REPLICATE_STRIDE = 100
"""Seed shift between replicates: replicate ``k`` adds ``k * REPLICATE_STRIDE`` to the
sampler seed, the base training seed (so every trial and final-phase training seed) and the
trials' and the final phase's held-out seed blocks. A study uses at most
``max(train_seeds, final_train_seeds)`` consecutive training seeds, which must be fewer."""

REPLICATES = "replicates"
"""The folder of a study's replicates, ``<results>/<study>/replicates/r<k>/``, and the stem of
its table, ``<results>/<study>/replicates.parquet`` and ``.md``."""

EXPERT = "expert"
"""The expert's label in the final phase's tables (``safe_bc.study.final.EXPERT``)."""
PLAIN_BC = "plain_bc"
"""Plain BC's label in the final phase's tables (``safe_bc.study.final.PLAIN_BC``)."""


def replicate_spec(spec: StudySpec, k: int) -> StudySpec:
    """Replicate ``k`` of ``spec``: the same study (space, budget, constraints, demonstrations)
    with its seeds shifted by ``k * REPLICATE_STRIDE`` (sampler, base training seed, trial
    evaluation block, final-phase block), named ``r<k>``, writing to
    ``<results>/<study>/replicates/r<k>/`` and its Tune experiment to
    ``<storage>/<study>_replicates/r<k>``. Replicate 0 keeps the study's seeds. Its Optuna copy
    is the SQLite file in its own folder (``optuna_storage=None``).

    Raises:
        ValueError: ``k < 0``; a study whose seeds would overlap between replicates (more
            training seeds than the stride, or evaluation and final blocks a multiple of the
            stride apart); held-out seed blocks beyond the seed range.
    """
    if isinstance(k, bool) or not isinstance(k, int) or k < 0:
        raise ValueError(f"replicate index must be an integer >= 0, got {k!r}")
    used = max(spec.train_seeds, spec.final_train_seeds)
    if used > REPLICATE_STRIDE:
        raise ValueError(
            f"{spec.name}: {used} training seeds per trial do not fit a replicate's block of "
            f"{REPLICATE_STRIDE}"
        )
    blocks = {"eval_seed": spec.eval_seed, "final_seed": spec.final_seed}
    if spec.certify_episodes:
        blocks["certify_seed"] = spec.certify_seed
    names = list(blocks)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if (blocks[b] - blocks[a]) % REPLICATE_STRIDE == 0:
                raise ValueError(
                    f"{spec.name}: {a} {blocks[a]} and {b} {blocks[b]} are a multiple of "
                    f"{REPLICATE_STRIDE} apart: one replicate's tracks would be another's"
                )
    shift = k * REPLICATE_STRIDE
    shifted = {name: block + shift for name, block in blocks.items()}
    try:
        for block in shifted.values():
            heldout_seed(block, 0)
    except ValueError:
        raise ValueError(
            f"{spec.name}: replicate {k}'s held-out seed blocks "
            f"({', '.join(str(b) for b in shifted.values())}) are beyond the seed range; use "
            "fewer replicates"
        ) from None
    train = replace(spec.base.bc.train, seed=spec.base.bc.train.seed + shift)
    base = replace(spec.base, bc=replace(spec.base.bc, train=train))
    return replace(
        spec,
        name=f"r{k}",
        base=base,
        sampler_seed=spec.sampler_seed + shift,
        **shifted,
        results=replicates_folder(spec),
        storage=f"{spec.storage.rstrip('/')}/{spec.name}_{REPLICATES}",
        optuna_storage=None,
    )


def replicates_folder(spec: StudySpec) -> Path:
    """``<results>/<study>/replicates``: the replicates' study folders are ``r<k>`` in it."""
    return spec.results / spec.name / REPLICATES


def replicate_seeds(spec: StudySpec) -> dict[str, int]:
    """The seeds that tell a replicate from another (the table's seed columns; the
    certification's block only where the study certifies)."""
    seeds = {
        "sampler_seed": spec.sampler_seed,
        "train_seed": spec.base.bc.train.seed,
        "eval_seed": spec.eval_seed,
        "final_seed": spec.final_seed,
    }
    if spec.certify_episodes:
        seeds["certify_seed"] = spec.certify_seed
    return seeds


def direction(lo: float, hi: float) -> str:
    """What an interval on a difference supports: ``"above"`` (``lo > 0``), ``"below"``
    (``hi < 0``), ``"spans zero"`` (no reliable effect), ``"missing"`` (NaN).

    >>> direction(-5.1, -1.2), direction(-1.2, 0.2), direction(0.1, 3.0), direction(math.nan, 1)
    ('below', 'spans zero', 'above', 'missing')
    """
    lo, hi = float(lo), float(hi)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return "missing"
    if lo > 0:
        return "above"
    if hi < 0:
        return "below"
    return "spans zero"


@dataclass(frozen=True)
class ReplicateResult:
    """What one finished replicate's final phase wrote (read by the caller, not here)."""

    replicate: int
    """Its index ``k``."""
    seeds: Mapping[str, int]
    """:func:`replicate_seeds` of its spec."""
    winner: str | None
    """The final phase's winner (trial id); ``None``: no final phase (no trial finished)."""
    winner_feasible: bool
    """Whether the winner met both constraints on the fresh tracks."""
    params: Mapping[str, Any]
    """The winner's searched parameters (``best.json``'s ``params``)."""
    final: pd.DataFrame
    """``final.parquet``: one row per method (``method``, ``reward``, ``reward_lo``,
    ``reward_hi``, ``n_episodes``, ``episodes_with_violation``, ``violation_share_ucb``)."""
    paired: pd.DataFrame
    """``final_paired.parquet``: ``method``, ``vs``, ``d_reward``, ``d_reward_lo``,
    ``d_reward_hi``, ``n_pairs``."""
    certificate: Mapping[str, Any] | None = None
    """The winner's certificate on the replicate's own certification block
    (``certify.parquet``'s metadata; :func:`safe_bc.study.certify.certify`), ``None``
    where the study does not certify."""


ROW_COLUMNS = (
    "replicate", "sampler_seed", "train_seed", "eval_seed", "final_seed", "winner",
    "winner_feasible", "reward", "reward_lo", "reward_hi", "expert_reward", "plain_bc_reward",
    "d_expert", "d_expert_lo", "d_expert_hi", "vs_expert", "d_plain_bc", "d_plain_bc_lo",
    "d_plain_bc_hi", "vs_plain_bc", "n_pairs", "crossings", "n_episodes", "crossings_ucb",
)  # fmt: skip
"""The replicate table's columns, in order; the certification's (:data:`CERT_COLUMNS`, where
the study certifies) and the winner's parameters (dotted names) follow."""

CERT_COLUMNS = (
    "certify_seed", "cert_method", "cert_beyond", "cert_episodes", "cert_beyond_ucb",
    "cert_deferred", "cert_reward", "cert_d_expert", "cert_d_expert_lo", "cert_d_expert_hi",
    "cert_vs_expert",
)  # fmt: skip
"""The certificate's columns: its block, what was certified (``recommender``: the agent with
its handover), its episodes beyond ``d_s`` of ``cert_episodes`` and their one-sided 95% bound,
the mean share of deferred steps, the reward and its paired difference to the expert on the
same tracks."""


def _value(frame: pd.DataFrame, where: Mapping[str, str], column: str) -> float:
    if frame.empty or column not in frame:
        return math.nan
    mask = np.ones(len(frame), bool)
    for key, value in where.items():
        if key not in frame:
            return math.nan
        mask &= (frame[key] == value).to_numpy()
    rows = frame.loc[mask, column]
    return float(rows.iloc[0]) if len(rows) else math.nan


def replicate_row(result: ReplicateResult, params: Sequence[str]) -> dict[str, Any]:
    """One row of the replicate table from a replicate's final-phase tables (NaN where the
    replicate has no final phase or a table lacks a value)."""
    w = result.winner or ""
    me = {"method": w}
    row: dict[str, Any] = {"replicate": result.replicate, **dict(result.seeds), "winner": w}
    row["winner_feasible"] = bool(result.winner_feasible and w)
    for col in ("reward", "reward_lo", "reward_hi"):
        row[col] = _value(result.final, me, col)
    row["expert_reward"] = _value(result.final, {"method": EXPERT}, "reward")
    row["plain_bc_reward"] = _value(result.final, {"method": PLAIN_BC}, "reward")
    for vs in (EXPERT, PLAIN_BC):
        key = {"method": w, "vs": vs}
        for suffix in ("", "_lo", "_hi"):
            row[f"d_{vs}{suffix}"] = _value(result.paired, key, f"d_reward{suffix}")
        row[f"vs_{vs}"] = direction(row[f"d_{vs}_lo"], row[f"d_{vs}_hi"])
    row["n_pairs"] = _value(result.paired, {"method": w, "vs": EXPERT}, "n_pairs")
    row["crossings"] = _value(result.final, me, "episodes_with_violation")
    row["n_episodes"] = _value(result.final, me, "n_episodes")
    row["crossings_ucb"] = _value(result.final, me, "violation_share_ucb")
    cert = result.certificate or {}
    row["certify_seed"] = result.seeds.get("certify_seed", math.nan)
    row["cert_method"] = str(cert.get("method", ""))
    for col, key in (
        ("cert_beyond", "episodes_beyond"),
        ("cert_episodes", "episodes"),
        ("cert_beyond_ucb", "beyond_ucb95"),
        ("cert_deferred", "deferred_share"),
        ("cert_reward", "reward"),
    ):
        row[col] = float(cert.get(key, math.nan))
    d = list(cert.get("d_reward_vs_expert") or [math.nan] * 3)
    row["cert_d_expert"], row["cert_d_expert_lo"], row["cert_d_expert_hi"] = map(float, d)
    row["cert_vs_expert"] = direction(row["cert_d_expert_lo"], row["cert_d_expert_hi"])
    row.update({p: result.params.get(p) if w else None for p in params})
    return row


def replicate_table(results: Sequence[ReplicateResult], params: Sequence[str]) -> pd.DataFrame:
    """One row per replicate (:data:`ROW_COLUMNS`, then the winner's ``params``), in
    replicate order. Parameter values become text (a choice may be a number in one replicate
    and a label in another; Parquet needs one type per column)."""
    rows = [replicate_row(r, params) for r in sorted(results, key=lambda r: r.replicate)]
    certified = any(r.certificate for r in results)
    table = pd.DataFrame(
        rows, columns=[*ROW_COLUMNS, *(CERT_COLUMNS if certified else ()), *params]
    )
    for p in params:
        table[p] = table[p].map(lambda v: "" if v is None else str(v))
    for c in ("crossings", "n_episodes", "n_pairs"):
        table[c] = table[c].astype(float)
    return table


def replicates_summary(table: pd.DataFrame) -> dict[str, Any]:
    """Across replicates: the mean and range of the winner-vs-expert reward difference, how
    many replicates' intervals lie above / below zero or span it (vs the expert and vs plain
    BC), the total episodes beyond ``d_s``, how many distinct configurations won (trial ids
    are per study and say nothing across replicates) and the :func:`replicates_verdict`."""
    params = [c for c in table.columns if c not in ROW_COLUMNS and c not in CERT_COLUMNS]
    d = table["d_expert"].astype(float)
    finite = d[np.isfinite(d)]
    out: dict[str, Any] = {
        "replicates": len(table),
        "with_winner": int((table["winner"] != "").sum()),
        "winner_feasible": int(table["winner_feasible"].sum()),
        "distinct_configurations": int(
            table.loc[table["winner"] != "", params].drop_duplicates().shape[0]
        ),
        "d_expert_mean": float(finite.mean()) if len(finite) else math.nan,
        "d_expert_min": float(finite.min()) if len(finite) else math.nan,
        "d_expert_max": float(finite.max()) if len(finite) else math.nan,
    }
    for vs in (EXPERT, PLAIN_BC):
        counts = table[f"vs_{vs}"].value_counts()
        for label in ("above", "below", "spans zero", "missing"):
            out[f"{vs}_{label.replace(' ', '_')}"] = int(counts.get(label, 0))
    out["crossings_total"] = int(np.nansum(table["crossings"].astype(float)))
    out["episodes_total"] = int(np.nansum(table["n_episodes"].astype(float)))
    if "cert_method" in table:
        certified = table[table["cert_method"] != ""]
        dd = certified["cert_d_expert"].astype(float)
        counts = certified["cert_vs_expert"].value_counts()
        out["certified"] = len(certified)
        out["cert_beyond_total"] = int(np.nansum(certified["cert_beyond"].astype(float)))
        out["cert_episodes_total"] = int(np.nansum(certified["cert_episodes"].astype(float)))
        out["cert_deferred_max"] = float(certified["cert_deferred"].max()) if len(dd) else math.nan
        out["cert_d_expert_min"] = float(dd.min()) if len(dd) else math.nan
        out["cert_d_expert_max"] = float(dd.max()) if len(dd) else math.nan
        for label in ("above", "below", "spans zero"):
            out[f"cert_expert_{label.replace(' ', '_')}"] = int(counts.get(label, 0))
    out["verdict"] = replicates_verdict(out)
    return out


def _against(summary: Mapping[str, Any], vs: str, name: str) -> str:
    n = summary["replicates"] - summary[f"{vs}_missing"]
    above, below, span = (summary[f"{vs}_{k}"] for k in ("above", "below", "spans_zero"))
    if n == 0:
        return f"no replicate compared the winner with {name}"
    if below == n:
        return f"reliably below {name} in all {n} replicates"
    if above == n:
        return f"reliably above {name} in all {n} replicates"
    if span == n:
        return (
            f"not reliably different from {name} in any of the {n} replicates (every interval "
            "spans zero: no reliable effect)"
        )
    parts = [f"reliably below in {below}"] if below else []
    parts += [f"reliably above in {above}"] if above else []
    parts += [f"no reliable effect (interval spans zero) in {span}"] if span else []
    lead = (
        f"not above {name}" if not above else f"not below {name}" if not below else
        f"no consistent direction against {name}"
    )  # fmt: skip
    return f"{lead}: " + ", ".join(parts) + f" of {n} replicates"


def replicates_verdict(summary: Mapping[str, Any]) -> str:
    """The one line the replicates support: the winner against the expert and against plain
    BC (how many replicates' paired intervals lie below, above or span zero), the range of
    the difference to the expert, and the episodes beyond ``d_s``.

    >>> s = {"replicates": 4, "expert_above": 0, "expert_below": 3, "expert_spans_zero": 1,
    ...      "expert_missing": 0, "plain_bc_above": 0, "plain_bc_below": 0,
    ...      "plain_bc_spans_zero": 4, "plain_bc_missing": 0, "d_expert_mean": -1.4,
    ...      "d_expert_min": -2.3, "d_expert_max": -0.3, "crossings_total": 5,
    ...      "episodes_total": 204, "winner_feasible": 4}
    >>> print(replicates_verdict(s))  # doctest: +NORMALIZE_WHITESPACE
    the winner is not above the expert: reliably below in 3, no reliable effect (interval
    spans zero) in 1 of 4 replicates (reward difference mean -1.4, range -2.3 to -0.3);
    not reliably different from plain BC in any of the 4 replicates (every interval spans zero:
    no reliable effect); 5 of 204 final-phase episodes beyond d_s; 4 of 4 winners feasible on
    the fresh tracks
    """
    text = "the winner is " + _against(summary, EXPERT, "the expert")
    if math.isfinite(summary.get("d_expert_mean", math.nan)):
        text += (
            f" (reward difference mean {summary['d_expert_mean']:.1f}, range "
            f"{summary['d_expert_min']:.1f} to {summary['d_expert_max']:.1f})"
        )
    text += "; " + _against(summary, PLAIN_BC, "plain BC")
    text += (
        f"; {summary['crossings_total']} of {summary['episodes_total']} final-phase episodes "
        f"beyond d_s; {summary['winner_feasible']} of {summary['replicates']} winners feasible "
        "on the fresh tracks"
    )
    if summary.get("certified"):
        s = summary
        text += (
            f"; certified: {s['cert_beyond_total']} of {s['cert_episodes_total']} certification "
            f"episodes beyond d_s over {s['certified']} replicates (at most "
            f"{100 * s['cert_deferred_max']:.1f}% of steps deferred), against the expert reliably "
            f"above in {s['cert_expert_above']}, below in {s['cert_expert_below']}, no reliable "
            f"effect (interval spans zero) in {s['cert_expert_spans_zero']} (difference "
            f"{s['cert_d_expert_min']:+.1f} to {s['cert_d_expert_max']:+.1f})"
        )
    return text


def _interval(v: float, lo: float, hi: float) -> str:
    if not math.isfinite(v):
        return ""
    return f"{v:+.1f} [{lo:+.1f}, {hi:+.1f}]"


def replicates_markdown(
    table: pd.DataFrame, summary: Mapping[str, Any], params: Sequence[str], note: str = ""
) -> str:
    """``replicates.md``: the per-replicate table, the summary and the verdict (pandas
    ``to_markdown``); ``note`` (e.g. the command and the machine) closes it."""
    short = {p: p.rsplit(".", 1)[-1] for p in params}
    view = pd.DataFrame(
        {
            "replicate": table["replicate"],
            "seeds (sampler/train/eval/final)": [
                f"{r.sampler_seed}/{r.train_seed}/{r.eval_seed}/{r.final_seed}"
                for r in table.itertuples()
            ],
            "winner": table["winner"],
            "configuration": [
                " ".join(f"{short[p]}={_fmt(row[p])}" for p in params)
                for _, row in table.iterrows()
            ],
            "reward": table["reward"].map(lambda v: f"{v:.1f}" if math.isfinite(v) else ""),
            "vs expert (95% CI)": [
                _interval(*v) for v in table[["d_expert", "d_expert_lo", "d_expert_hi"]].values
            ],
            "vs plain BC (95% CI)": [
                _interval(*v)
                for v in table[["d_plain_bc", "d_plain_bc_lo", "d_plain_bc_hi"]].values
            ],
            "beyond d_s": [
                f"{int(c)}/{int(n)}" if math.isfinite(c) and math.isfinite(n) else ""
                for c, n in zip(table["crossings"], table["n_episodes"], strict=True)
            ],
            "share bound (CP)": table["crossings_ucb"].map(
                lambda v: f"{v:.3f}" if math.isfinite(v) else ""
            ),
            "feasible": table["winner_feasible"].map({True: "yes", False: "no"}),
        }
    )
    s = summary
    counts = pd.DataFrame(
        {
            "against": ["expert", "plain BC"],
            "reliably above": [s["expert_above"], s["plain_bc_above"]],
            "reliably below": [s["expert_below"], s["plain_bc_below"]],
            "spans zero": [s["expert_spans_zero"], s["plain_bc_spans_zero"]],
            "missing": [s["expert_missing"], s["plain_bc_missing"]],
        }
    )
    lines = [
        f"# Replicate studies ({s['replicates']} replicates)",
        "",
        "The winner of each replicate (the same study, seeds shifted) on its final phase's fresh "
        "tracks: reward, paired reward differences (winner minus reference, same tracks and "
        "seeds; 95% bootstrap CIs), episodes with a step beyond d_s and the one-sided "
        "Clopper-Pearson bound on their share.",
        "",
        view.to_markdown(index=False),
        "",
        "Replicates whose interval lies above zero, below it, or spans it:",
        "",
        counts.to_markdown(index=False),
        "",
        f"Winner minus expert across replicates: mean {s['d_expert_mean']:.1f}, range "
        f"{s['d_expert_min']:.1f} to {s['d_expert_max']:.1f}; {s['distinct_configurations']} "
        f"distinct winning configurations; {s['crossings_total']} of {s['episodes_total']} "
        "final-phase episodes beyond d_s.",
        "",
        *_certification_lines(table),
        f"**Verdict:** {s['verdict']}.",
    ]
    if note:
        lines += ["", note]
    return "\n".join(lines) + "\n"


def _certification_lines(table: pd.DataFrame) -> list[str]:
    """The certification's per-replicate table (none where the study does not certify)."""
    if "cert_method" not in table or not (table["cert_method"] != "").any():
        return []
    view = pd.DataFrame(
        {
            "replicate": table["replicate"],
            "block": table["certify_seed"].map(lambda v: f"{v:.0f}" if math.isfinite(v) else ""),
            "certified": table["cert_method"],
            "beyond d_s": [
                f"{int(c)}/{int(n)}" if math.isfinite(c) and math.isfinite(n) else ""
                for c, n in zip(table["cert_beyond"], table["cert_episodes"], strict=True)
            ],
            "share bound (CP)": table["cert_beyond_ucb"].map(
                lambda v: f"{v:.3f}" if math.isfinite(v) else ""
            ),
            "deferred": table["cert_deferred"].map(
                lambda v: f"{100 * v:.1f}%" if math.isfinite(v) else ""
            ),
            "reward": table["cert_reward"].map(lambda v: f"{v:.1f}" if math.isfinite(v) else ""),
            "vs expert (95% CI)": [
                _interval(*v)
                for v in table[["cert_d_expert", "cert_d_expert_lo", "cert_d_expert_hi"]].values
            ],
        }
    )
    return [
        "Each replicate's winner certified on its own block (the recommender: the agent with "
        "its handover; the expert on the same tracks):",
        "",
        view.to_markdown(index=False),
        "",
    ]


def _fmt(v: Any) -> str:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f"{x:.3g}" if not float(x).is_integer() else str(v)
