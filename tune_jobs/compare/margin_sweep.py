"""Safety-margin sweep for constrained improvement on the rehabilitation pathway: the
candidates on 3 training seeds and the *selection* patients.

Why: with the rehab defaults of the time (``cost_margin`` 0.02), 2 of 600 held-out
programmes of the Lagrangian agent and 4 of 600 of shield + Lagrangian had a session beyond
``d_s``. Each candidate in :data:`CANDIDATES` changes a few principled levers (a larger
safety margin inside ``d_s`` for the Lagrangian's cost, a smaller cost budget, more
validation patients for ``keep="best_feasible"``, an earlier shield).

Three disjoint patient sets, so that nothing is tuned on the test patients:

* *keep* patients, ``validation_seeds(eval_episodes)``: inside each run, pick the kept policy;
* *selection* patients, the validation patients from index :data:`SELECT_OFFSET` on (this
  comparison): compare candidates and choose;
* *test* patients: the 200 held-out patients of ``improve_rehab.py`` (evaluation seed 5),
  used once per chosen candidate (``margin_sweep_test.py``); every candidate ever tested is in
  :data:`TESTED`, in order.

Run: ``safe-bc compare tune_jobs/compare/margin_sweep_screen.py`` (every candidate, seed 0),
``safe-bc compare tune_jobs/compare/margin_sweep.py`` (the promising ones, 3 seeds),
``safe-bc compare tune_jobs/compare/margin_sweep_test.py`` (:data:`TESTED` on the test
patients), then ``python -m scripts.margin_sweep`` (the gains table, ``margin_sweep.md``,
from the episode tables). Outputs in ``results/improve/rehab/sweep/``; the three share their
starts and improvement runs (``sweep_runs/``); the test comparison's evaluations of the
rows it shares replace the selection ones (a later selection run evaluates them again).
"""

from dataclasses import replace
from pathlib import Path
from typing import Any

from safe_bc.compare import Comparison, Method
from safe_bc.improve.config import ImproveConfig
from safe_bc.selection import SelectionConfig

CANDIDATES: dict[str, dict[str, Any]] = {
    "lag_m0.02": {"shield": False, "lagrangian": True, "cost_margin": 0.02},
    "lag_m0.05": {"shield": False, "lagrangian": True, "cost_margin": 0.05},
    "lag_m0.1": {"shield": False, "lagrangian": True, "cost_margin": 0.1},
    "lag_m0.05_b0.05": {
        "shield": False,
        "lagrangian": True,
        "cost_margin": 0.05,
        "cost_budget": 0.05,
    },
    "lag_m0.05_v512": {
        "shield": False,
        "lagrangian": True,
        "cost_margin": 0.05,
        "eval_episodes": 512,
    },
    "lag_m0.1_v512": {
        "shield": False,
        "lagrangian": True,
        "cost_margin": 0.1,
        "eval_episodes": 512,
    },
    "both_m0.05": {"shield": True, "lagrangian": True, "cost_margin": 0.05},
    "both_m0.05_eps0.1": {"shield": True, "lagrangian": True, "cost_margin": 0.05, "eps": 0.1},
}
"""Candidate name -> :class:`ImproveConfig` overrides of :data:`BASE`."""
BASE = ImproveConfig(cost_margin=0.02, cost_budget=0.1, eval_episodes=128, keep="best_feasible")
"""The candidates' common base: the defaults at the time of the sweep (``cost_margin`` 0.02,
``cost_budget`` 0.1, ``eval_episodes`` 128, start eps 0.05), pinned so that later default
changes leave the sweep as it was."""
THREE_SEEDS = ["lag_m0.02", "lag_m0.05", "lag_m0.1", "lag_m0.1_v512", "both_m0.05",
               "both_m0.05_eps0.1"]  # fmt: skip
"""Run on 3 seeds: the three margins of the Lagrangian alone and the candidates with no
selection programme beyond d_s on seed 0."""
TESTED: list[str] = ["lag_m0.02", "lag_m0.1", "both_m0.05_eps0.1"]
"""Candidates evaluated on the test patients, in order (all reported): ``lag_m0.02`` is the
earlier default, whose test result was published before this sweep; ``lag_m0.1`` was the
sweep's choice at its first run (two-level bootstrap); ``both_m0.05_eps0.1`` is the
choice of its rerun (the highest 3-seed selection gain among the candidates with no
selection programme beyond ``d_s``: the only one left; ``lag_m0.1`` let 1 of 1536 cross)."""
SELECT_OFFSET = 1024
"""Selection patients start at validation index 1024 (keep patients use at most 512)."""
OUT = Path("results/improve/rehab/sweep")


def sweep(candidates: list[str]) -> tuple[Method, ...]:
    """The guideline clinician, the safety-imitation start (``safe-bc train --alpha 0.5``'s
    recipe, as in ``improve_rehab.py``) and one improvement row per candidate."""
    return (
        Method("expert", expert=True, label="guideline clinician (expert)"),
        Method("imitation", selection=SelectionConfig(eps=0.05, alpha=0.5)),
        *(Method(c, improve=replace(BASE, **CANDIDATES[c]), start="imitation") for c in candidates),
    )


COMPARISON = Comparison(
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
