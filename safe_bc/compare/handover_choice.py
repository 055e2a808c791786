"""Choosing a task's handover by measurement: candidates over a recommender's agents on
selection episodes, the rule fixed in the measurement's file before it runs, and the table the
rule reads (pure: no I/O, no Ray; ``scripts/handover_choice.py`` runs it)."""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from safe_bc.handover import Fallback, HandoverConfig
from safe_bc.metrics import clopper_pearson_upper, episodes_beyond, paired_to_reference

EXPERT = "expert"
"""Method label of the expert's own episodes on the selection block."""

Rule = Literal["fewest_deferred", "fewest_deferred_else_fewest_beyond", "best_lower_bound"]
"""``fewest_deferred``: among the candidates with no selection episode beyond ``d_s`` and a mean
deferred share below the limit, the fewest steps deferred; ties go to the higher reward; none
qualifies: none. ``fewest_deferred_else_fewest_beyond``: the same, and where none qualifies, among
the candidates below the deferral limit the fewest episodes beyond ``d_s``, then the fewest
steps deferred (a choice always, for a certificate to judge). ``best_lower_bound``: among the
candidates with no selection episode beyond ``d_s`` and a mean deferred share below the limit,
the highest lower bound of the paired reward interval against the expert (ties: fewer steps
deferred); none qualifies: none (an agent meant to beat the expert, where the zone's price in
reward counts, not only its share)."""

RULE_TEXT: dict[str, str] = {
    "fewest_deferred": "among the candidates with no episode beyond d_s and a mean deferred "
    "share below the limit, the fewest steps deferred; ties go to the higher reward",
    "fewest_deferred_else_fewest_beyond": "among the candidates with no episode beyond d_s and "
    "a mean deferred share below the limit, the fewest steps deferred (ties: the higher "
    "reward); where none has zero, among those below the limit the fewest episodes beyond d_s, "
    "then the fewest steps deferred",
    "best_lower_bound": "among the candidates with no episode beyond d_s and a mean deferred "
    "share below the limit, the highest lower bound of the paired reward interval against the "
    "expert; ties go to fewer steps deferred",
}
"""Each rule in words, for the measurement's Markdown."""


@dataclass(frozen=True)
class HandoverChoice:
    """One handover measurement: every candidate over the recommender's agents, on the same
    selection episodes for every candidate and training seed, beside the expert."""

    name: str
    """Names the measurement in its tables."""
    recommender: Path
    """The recommender folder whose agents, ``d_s`` and expert the candidates use (its own
    handover is ignored)."""
    candidates: tuple[HandoverConfig, ...]
    """The handovers measured, in the table's order."""
    eval_seed: int
    """The held-out seed block of the selection episodes (a block no other table uses)."""
    episodes: int
    """Selection episodes per training seed (the same ones for every candidate)."""
    deferred_limit: float
    """The rule's bound on the mean share of steps the expert is consulted."""
    out: Path
    """Folder of ``choice.parquet``, ``episodes.parquet`` and ``choice.md``."""
    rule: Rule = "fewest_deferred"
    """The rule that picks the row (:data:`Rule`), fixed before the run."""


def handover_grid(
    widths: Mapping[str, Sequence[float]], fallbacks: Sequence[Fallback] = ("expert",)
) -> tuple[HandoverConfig, ...]:
    """Every combination of per-dimension widths and fallbacks, as handovers (``width`` is the
    largest of a row's widths; every dimension is named in ``widths``).

    >>> [h.label() for h in handover_grid({"a": (0.1,), "b": (0.1, 0.2)})][1]
    'expert within w of d_s (w: a 0.1, b 0.2; else 0.2)'
    """
    dims = list(widths)
    out = []
    for fallback in fallbacks:
        for combo in itertools.product(*(widths[d] for d in dims)):
            pairs = tuple(zip(dims, (float(w) for w in combo), strict=True))
            out.append(HandoverConfig(max(combo), widths=pairs, fallback=fallback))
    return tuple(out)


def candidate_label(i: int) -> str:
    """The method label of candidate ``i`` in the episodes table."""
    return f"h{i:02d}"


def choice_table(episodes: pd.DataFrame, choice: HandoverChoice) -> pd.DataFrame:
    """One row per candidate: episodes, those beyond ``d_s`` with the one-sided 95% bound, the
    mean deferred share, the reward and its paired difference to the expert on the same
    episodes (crossed bootstrap over training seeds and episodes), and the handover itself.
    ``episodes`` has ``method`` (a :func:`candidate_label` or :data:`EXPERT`), ``train_seed``,
    ``env_seed``, ``reward``, ``deferred_share`` and the beyond-d_s columns."""
    beyond = pd.Series(episodes_beyond(episodes), index=episodes.index)
    paired = paired_to_reference(episodes, EXPERT, ["reward"], seed=choice.eval_seed)
    paired = paired.set_index("method")
    rows = []
    for i, h in enumerate(choice.candidates):
        label = candidate_label(i)
        mine = episodes["method"] == label
        k, n = int(beyond[mine].sum()), int(mine.sum())
        rows.append(
            {
                "candidate": label,
                "handover": h.label(),
                "fallback": h.fallback,
                **{f"width_{d}": w for d, w in h.widths},
                "episodes": n,
                "episodes_beyond": k,
                "beyond_ucb95": clopper_pearson_upper(k, n) if n else np.nan,
                "deferred_share": float(episodes.loc[mine, "deferred_share"].mean()),
                "reward": float(episodes.loc[mine, "reward"].mean()),
                "d_reward_vs_expert": float(paired.loc[label, "d_reward"]),
                "d_reward_lo": float(paired.loc[label, "d_reward_lo"]),
                "d_reward_hi": float(paired.loc[label, "d_reward_hi"]),
            }
        )
    table = pd.DataFrame(rows)
    mine = episodes["method"] == EXPERT
    expert = {
        "candidate": EXPERT,
        "handover": "the expert alone",
        "episodes": int(mine.sum()),
        "episodes_beyond": int(beyond[mine].sum()),
        "beyond_ucb95": clopper_pearson_upper(int(beyond[mine].sum()), int(mine.sum())),
        "reward": float(episodes.loc[mine, "reward"].mean()),
    }
    return pd.concat([table, pd.DataFrame([expert])], ignore_index=True)


def choose(table: pd.DataFrame, choice: HandoverChoice) -> int | None:
    """The index (into ``choice.candidates``) the rule picks from :func:`choice_table`'s rows;
    ``None`` when no candidate qualifies.

    >>> t = pd.DataFrame({"candidate": ["h00", "h01", "h02"], "episodes_beyond": [0, 1, 0],
    ...                   "deferred_share": [0.08, 0.01, 0.06], "reward": [1.0, 2.0, 0.5]})
    >>> c = HandoverChoice("x", Path("r"), (), 0, 1, 0.1, Path("o"))
    >>> choose(t, c)
    2
    >>> t["d_reward_lo"] = [0.5, 3.0, 0.2]
    >>> import dataclasses
    >>> choose(t, dataclasses.replace(c, rule="best_lower_bound"))
    0
    """
    rows = table[table["candidate"] != EXPERT]
    light = rows[rows["deferred_share"] < choice.deferred_limit]
    ok = light[light["episodes_beyond"] == 0]
    if ok.empty and choice.rule == "fewest_deferred_else_fewest_beyond" and not light.empty:
        best = light.sort_values(["episodes_beyond", "deferred_share"]).iloc[0]
        return int(str(best["candidate"])[1:])
    if ok.empty:
        return None
    if choice.rule == "best_lower_bound":
        best = ok.sort_values(["d_reward_lo", "deferred_share"], ascending=[False, True]).iloc[0]
        return int(str(best["candidate"])[1:])
    best = ok.sort_values(["deferred_share", "reward"], ascending=[True, False]).iloc[0]
    return int(str(best["candidate"])[1:])
