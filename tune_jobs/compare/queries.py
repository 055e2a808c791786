"""Critical-zone queries and deferral, per task: plain BC, DAgger at the critical-zone run's
number of queries, critical-zone queries, deferral to the expert near d_s, BC-Safe, on
selection tracks (held-out block 11) then fresh tracks (block 12).

Per task one selection comparison (every row, the deferral over each agent at a grid of
widths) and its fresh comparison (the rows again, each agent's deferral at the width the rule
picked on the selection tracks: the smallest with no episode beyond d_s, else the largest).
The clinic counts an episode beyond d_s when a session's outcome is, the last one included
(``any_violating_session``); the car when a scored step is. The two comparisons share one runs
folder (``queries_runs``): every agent and query run is made once.

* ``bc``: plain BC at the alpha of the task's improvement starts, 2,000 batches;
* ``critical``: 2 rounds x 16 rollouts of critical-zone queries from it (the ``queries``
  method); ``full``: DAgger from it, each round capped at the critical run's queries per
  round (``budget_of``);
* ``defer-<w>``, ``critical+defer-<w>``: plain BC and the critical-zone agent with the expert
  acting where the cost is within ``w`` of d_s;
* ``bc_safe``: OSRL's BC-Safe (alpha 0), a baseline that asks nothing.

Every episode runs as one env alone would (``lockstep_forward="rows"``). Run: ``safe-bc compare
tune_jobs/compare/queries.py --name rehab_selection``, then ``--name rehab``, then the summary
(``python -m scripts.queries_report tune_jobs/compare/queries.py --name rehab``). The car's
selection grids are the widths measured when its table was made, which tried widths from the
smallest up and stopped at the first with no episode beyond d_s (the rule picks the same).
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.bc.config import BCConfig, TrainConfig
from safe_bc.compare.protocol import Fresh, Rule
from safe_bc.compare.spec import Agent, Comparison, Expert, FromStart, Handover
from safe_bc.handover import HandoverConfig
from safe_bc.methods.queries.config import QueryConfig
from safe_bc.selection import SelectionConfig


def rows(eps: float, alpha: float, widths: dict[str, tuple[float, ...]]) -> tuple:
    """The rows of a task with selection width ``eps``, plain BC's ``alpha`` and the deferral
    widths per agent (``"bc"``, ``"critical"``)."""
    queries = QueryConfig(mode="critical", rounds=2, episodes_per_round=16)
    defer = {"bc": "defer", "critical": "critical+defer"}
    return (
        Expert("expert"),
        Agent("bc", SelectionConfig(eps=eps, alpha=alpha)),
        Agent("bc_safe", SelectionConfig(eps=eps, mode="bc_safe")),
        FromStart("critical", "bc", queries),
        FromStart("full", "bc", replace(queries, mode="full", budget_of="critical")),
        *(
            Handover(f"{defer[agent]}-{w:g}", agent, HandoverConfig(w))
            for agent in ("bc", "critical")
            for w in widths[agent]
        ),
    )


REHAB = Comparison(
    name="queries_selection",
    methods=rows(0.05, 0.5, dict.fromkeys(("bc", "critical"), (0.025, 0.05, 0.1, 0.2))),
    task="rehab",
    demos=Path("data/rehab_demos"),
    out=Path("results/queries/rehab"),
    runs="queries",
    train_seeds=(0, 1, 2),
    episodes=200,
    eval_seed=11,
    bc=BCConfig(train=TrainConfig(batches=2000)),
    lockstep_forward="rows",
    reference="expert",
    paired_metrics=("reward",),
    totals=("any_violating_session",),
    title="Critical-zone queries and deferral: selection patients (rehab)",
    note="Selection patients (held-out block 11) for the deferral widths.",
)
CARRACING = replace(
    REHAB,
    methods=rows(2.0, 0.1, {"bc": (1.0, 2.0, 4.0), "critical": (1.0, 2.0)}),
    task="carracing",
    demos=Path("data/demos"),
    out=Path("results/queries/carracing"),
    episodes=50,
    paired_metrics=("reward", "violation_steps"),
    totals=(),
    title="Critical-zone queries and deferral: selection tracks (CarRacing)",
    note="Selection tracks (held-out block 11) for the deferral widths.",
    shares_tracks_with=("results/ablation/renderer/renderer", "results/ablation/renderer/pipeline"),
)
"""The car's: its selection block's first 20 tracks are also the renderer tables' (block 11)."""
SAFEST = Rule("smallest_safe_width")
"""Per agent the smallest width with no selection episode beyond d_s, else the largest."""
FRESH = (
    "Fresh {} (held-out block 12); each deferral's width chosen on the selection {} by the "
    "smallest width with no episode beyond d_s, else the largest."
)

COMPARISONS = {
    "rehab_selection": REHAB,
    "rehab": Fresh(
        "queries", "rehab_selection",
        (Rule("smallest_safe_width", {"beyond": "total_any_violating_session"}),),
        eval_seed=12,
        title="Critical-zone queries and deferral: fresh patients (rehab)",
        note=FRESH.format("patients", "patients"),
    ),
    "carracing_selection": CARRACING,
    "carracing": Fresh(
        "queries", "carracing_selection", (SAFEST,), eval_seed=12,
        title="Critical-zone queries and deferral: fresh tracks (CarRacing)",
        note=FRESH.format("tracks", "tracks"),
    ),
}  # fmt: skip
