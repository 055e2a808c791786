"""Which self-imitation setting a selection table supports: the report step of the
self-imitation family's selection tables (pure: the table and its metadata in, Markdown out).

``tune_jobs/compare/selfimprove.py``'s ``selection_<task>`` and ``rounds_carracing`` declare
``Report("safe_bc.methods.selfimprove.choice:markdown", ...)``: the runner
(:func:`safe_bc.compare.run.run_report`) hands :func:`markdown` the table it wrote (one row per
method, paired columns against the start) and writes the text beside it (``choice.md`` beside
``selection.parquet``, ``rounds_choice.md`` beside ``rounds.parquet``); ``safe-bc compare
tune_jobs/compare/selfimprove.py --name selection_<task> --report-only`` reruns only this step
from the committed table.

The rule (:func:`choose`), written after the rehab table and before the CarRacing table
existed (in ``scripts/selfimprove_choice.py``, the name the Markdown keeps; docs/history.md):

1. candidates are the self-imitation rows whose reward gain over the start is reliable (the
   paired crossed 95% interval lies above 0);
2. among them, the fewest episodes beyond d_s (summed over seeds x tracks), then the highest
   reward;
3. the chosen row's setting becomes the default of that testbed; without a candidate the
   defaults stay, and the table says no setting gave a reliable gain.

Each row also gets the one-sided 95% Clopper-Pearson upper bound on its share of episodes
beyond d_s. The rows are one-at-a-time changes of the defaults: a combination of two
choices is not measured by this table.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.metrics import clopper_pearson_upper

BEYOND = {"carracing": "episodes_with_violation", "rehab": "total_any_violating_session"}
"""Each task's count of episodes beyond d_s in a comparison table (CarRacing: an episode
with a scored step beyond; rehab: a programme with a session outcome beyond, the last one
included)."""


def choose(table: pd.DataFrame, beyond: str, rows: list[str]) -> tuple[str | None, str]:
    """The chosen row among ``rows`` (self-imitation rows of ``table``, indexed by method)
    and why; ``None`` when no row's reward gain over the start is reliable.

    >>> t = pd.DataFrame({"d_reward_lo": [0.1, 0.2, -0.1], "b": [5, 3, 0],
    ...                   "reward": [1.0, 2.0, 3.0]}, index=["defaults", "x", "y"])
    >>> choose(t, "b", ["defaults", "x", "y"])[0]
    'x'
    >>> choose(t.assign(d_reward_lo=-1.0), "b", ["defaults", "x", "y"])[0] is None
    True
    """
    sub = table.loc[rows]
    reliable = sub[sub["d_reward_lo"] > 0]
    if reliable.empty:
        return None, "no row's reward gain over the start is reliable (every interval reaches 0)"
    ranked = reliable.assign(_b=reliable[beyond]).sort_values(
        ["_b", "reward"], ascending=[True, False], kind="stable"
    )
    best = str(ranked.index[0])
    return best, (
        f"{len(reliable)} of {len(sub)} rows gain reliably over the start; {best} has the "
        f"fewest episodes beyond d_s among them ({int(ranked['_b'].iloc[0])}), then the "
        "highest reward"
    )


def choice_table(
    table: pd.DataFrame, beyond: str, rows: list[str], labels: dict[str, str]
) -> pd.DataFrame:
    """One line per row: reward and its gain over the start, episodes beyond d_s with their
    upper bound, and whether the gain is reliable."""
    out = []
    for name in rows:
        r = table.loc[name]
        n = int(r["n_episodes"])
        k = int(r[beyond])
        out.append(
            {
                "row": name,
                "label": labels.get(name, name),
                "seeds x tracks": f"{int(r['n_train_seeds'])} x {int(r['n_tracks'])}",
                "reward": f"{r['reward']:.2f} [{r['reward_lo']:.2f}, {r['reward_hi']:.2f}]",
                "reward - start": f"{r['d_reward']:+.2f} [{r['d_reward_lo']:+.2f}, "
                f"{r['d_reward_hi']:+.2f}]",
                "reliable gain": "yes" if r["d_reward_lo"] > 0 else "no",
                "episodes beyond d_s": f"{k}/{n}",
                "95% upper bound": f"{clopper_pearson_upper(k, n):.1%}",
            }
        )
    return pd.DataFrame(out)


def markdown(table: pd.DataFrame, meta: dict[str, Any], source: Path, command: str) -> str:
    """The choice as Markdown: the rule, each row, the chosen one (the report step,
    :class:`~safe_bc.compare.spec.Report`): from ``table`` and its provenance ``meta`` as the
    runner wrote them at ``source``, naming ``command`` as the command that made it."""
    task = meta["config"]["task"]
    beyond = BEYOND[task]
    rows = [m["name"] for m in meta["config"]["methods"] if m.get("selfimprove")]
    labels = {m["name"]: m.get("label") or m["name"] for m in meta["config"]["methods"]}
    indexed = table.set_index("method")
    chosen, why = choose(indexed, beyond, rows)
    start = indexed.loc[meta["config"]["reference"]]
    expert = indexed.loc["expert"] if "expert" in indexed.index else None
    lines = [
        f"# Self-imitation on {task}: the setting the selection table supports",
        "",
        f"From `{source}` (code {meta['git_revision'][:10]}; "
        f"{meta['config']['episodes']} selection tracks of block {meta['config']['eval_seed']} "
        f"x training seeds {meta['config']['train_seeds']}). Rule (written after the rehab table "
        "and before the CarRacing table existed, `scripts/selfimprove_choice.py`): among the "
        "self-imitation rows whose reward gain over the start is reliable (paired crossed 95% "
        "CI above 0), the fewest "
        "episodes beyond d_s, then the highest reward.",
        "",
        f"Start: reward {start['reward']:.2f}, {int(start[beyond])}/{int(start['n_episodes'])} "
        "episodes beyond d_s"
        + (
            f"; expert: {expert['reward']:.2f}, {int(expert[beyond])}/{int(expert['n_episodes'])}."
            if expert is not None
            else "."
        ),
        "",
        choice_table(indexed, beyond, rows, labels).to_markdown(index=False),
        "",
        f"**Chosen: {chosen}** ({why})." if chosen else f"**No change to the defaults**: {why}.",
        "",
        "The rows are one-at-a-time changes of the defaults; combinations are not measured "
        f"here. Command: `{command}`.",
        "",
    ]
    return "\n".join(lines)
