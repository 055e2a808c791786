"""Safety-margin sweep for constrained improvement on the rehabilitation pathway.

Each candidate in :data:`CANDIDATES` changes a few levers of :data:`BASE` (a larger safety
margin inside ``d_s`` for the Lagrangian's cost, a smaller cost budget, more validation
patients for ``keep="best_feasible"``, an earlier shield). Three disjoint patient sets, so
that nothing is tuned on the test patients:

* *keep* patients, ``validation_seeds(eval_episodes)``: inside each run, pick the kept policy;
* *selection* patients, the validation patients from index :data:`SELECT_OFFSET` on:
  ``sweep_screen_seed0`` (every candidate, training seed 0) and ``sweep_selection`` (the
  promising ones, :data:`THREE_SEEDS`, 3 seeds) compare candidates and choose;
* *test* patients, the 200 held-out patients of ``improve_rehab`` (block 5):
  ``sweep_test`` evaluates every candidate ever chosen (:data:`TESTED`, in order) once.

Rows: the guideline clinician (the paired reference), the safety-imitation start (BC with
alpha 0.5, eps 0.05) and one improvement row per candidate. The three share their starts and
improvement runs (``sweep_runs/``).

Run: ``safe-bc compare tune_jobs/compare/margin_sweep.py --name NAME`` for
``sweep_screen_seed0``, ``sweep_selection``, ``sweep_test``, then ``python -m
scripts.margin_sweep`` (the gains table, ``margin_sweep.md``, from the episode tables).
Outputs in ``results/improve/rehab/sweep/``.
"""

from dataclasses import replace
from pathlib import Path
from typing import Any

from safe_bc.compare.spec import Agent, Comparison, Expert, FromStart, Row
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.selection import SelectionConfig

CANDIDATES: dict[str, dict[str, Any]] = {
    "lag_m0.02": {"shield": False, "lagrangian": True, "cost_margin": 0.02},
    "lag_m0.05": {"shield": False, "lagrangian": True, "cost_margin": 0.05},
    "lag_m0.1": {"shield": False, "lagrangian": True, "cost_margin": 0.1},
    "lag_m0.05_b0.05": {"shield": False, "lagrangian": True, "cost_margin": 0.05,
                        "cost_budget": 0.05},
    "lag_m0.05_v512": {"shield": False, "lagrangian": True, "cost_margin": 0.05,
                       "eval_episodes": 512},
    "lag_m0.1_v512": {"shield": False, "lagrangian": True, "cost_margin": 0.1,
                      "eval_episodes": 512},
    "both_m0.05": {"shield": True, "lagrangian": True, "cost_margin": 0.05},
    "both_m0.05_eps0.1": {"shield": True, "lagrangian": True, "cost_margin": 0.05, "eps": 0.1},
}  # fmt: skip
"""Candidate name -> :class:`ImproveConfig` overrides of :data:`BASE`."""
BASE = ImproveConfig(cost_margin=0.02, cost_budget=0.1, eval_episodes=128, keep="best_feasible")
"""The candidates' common base (``cost_margin`` 0.02, ``cost_budget`` 0.1, ``eval_episodes``
128, start eps 0.05), pinned so that default changes leave the sweep as it is."""
THREE_SEEDS = ["lag_m0.02", "lag_m0.05", "lag_m0.1", "lag_m0.1_v512", "both_m0.05",
               "both_m0.05_eps0.1"]  # fmt: skip
"""Run on 3 seeds: the three margins of the Lagrangian alone and the candidates with no
selection programme beyond d_s on seed 0."""
TESTED: list[str] = ["lag_m0.02", "lag_m0.1", "both_m0.05_eps0.1"]
"""Candidates evaluated on the test patients, in the order they were chosen (all reported;
docs/improvement.md tells why each)."""
SELECT_OFFSET = 1024
"""Selection patients start at validation index 1024 (keep patients use at most 512)."""
OUT = Path("results/improve/rehab/sweep")


def sweep(candidates: list[str]) -> tuple[Row, ...]:
    """The guideline clinician, the safety-imitation start and one row per candidate."""
    return (
        Expert("expert", label="guideline clinician (expert)"),
        Agent("imitation", SelectionConfig(eps=0.05, alpha=0.5)),
        *(FromStart(c, "imitation", replace(BASE, **CANDIDATES[c])) for c in candidates),
    )


SELECTION = Comparison(
    name="sweep_selection",
    runs="sweep",
    methods=sweep(THREE_SEEDS),
    task="rehab",
    demos=Path("data/rehab_demos"),
    out=OUT,
    train_seeds=(0, 1, 2),
    episodes=512,
    tracks="validation",
    first_track=SELECT_OFFSET,
    workers=0,
    reference="expert",
    paired_metrics=("reward", "violating_sessions"),
    totals=("any_violating_session",),
    title="Margin sweep: candidates on the selection patients",
)

COMPARISONS = (
    replace(
        SELECTION,
        name="sweep_screen_seed0",
        methods=sweep(list(CANDIDATES)),
        train_seeds=(0,),
        title="Margin sweep screening: every candidate on seed 0, selection patients",
    ),
    SELECTION,
    replace(
        SELECTION,
        name="sweep_test",
        methods=sweep(TESTED),
        episodes=200,
        eval_seed=5,
        tracks="heldout",
        first_track=0,
        title="Margin sweep: tested candidates on the held-out patients",
        shares_tracks_with=("results/improve/rehab/improve",),
    ),
)
