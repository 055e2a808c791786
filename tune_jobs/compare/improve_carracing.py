"""Beyond the expert on CarRacing: constrained improvement from pixels, 3 seeds x 4 modes.

Rows: the expert; the safety-imitation start (BC with alpha 0.1, the default network and
budget: the paired columns' reference); one :func:`safe_bc.improve.improve` run per mode
from each seed's start (``PPO``: neither mechanism, shield only, Lagrangian only, both),
sized for pixels on small machines: 4 complete 1000-step episodes per PPO iteration, 20
iterations, validation on 4 tracks every 5 iterations, a cost margin of 1 px inside d_s.
Every policy on the same 50 fresh held-out tracks (seed block 7, used by no other table).

Run: ``safe-bc compare tune_jobs/compare/improve_carracing.py`` (hours on 2 cores; every
start, run and evaluation resumes per method and seed). Writes
``results/improve/carracing/improve*.parquet`` (``improve_history.parquet``: the learning
curves) and ``improve.md``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import Comparison, Method
from safe_bc.improve.config import ImproveConfig
from safe_bc.selection import SelectionConfig

BASE = ImproveConfig(
    iterations=20,
    episodes_per_iter=4,
    n_envs=4,
    eval_every=5,
    eval_episodes=4,
    cost_margin=1.0,
    checkpoint_every=1,
)
START = "safety-imitation start (alpha 0.1)"
MODES = {
    "PPO, neither mechanism": (False, False),
    "shield only": (True, False),
    "Lagrangian only": (False, True),
    "shield + Lagrangian": (True, True),
}

COMPARISON = Comparison(
    name="improve",
    methods=(
        Method("expert", expert=True),
        Method(START, selection=SelectionConfig(eps=2.0, alpha=0.1)),
        *(
            Method(name, improve=replace(BASE, shield=shield, lagrangian=lagrangian), start=START)
            for name, (shield, lagrangian) in MODES.items()
        ),
    ),
    task="carracing",
    out=Path("results/improve/carracing"),
    train_seeds=(0, 1, 2),
    episodes=50,
    eval_seed=7,
    reference=START,
    paired_metrics=("reward", "violation_steps"),
    title="Beyond the expert: constrained improvement on CarRacing",
    note="Paired rows: each improved agent against its own seed's start on the same tracks.",
)
