"""Self-imitation on the rehabilitation pathway against the PPO-Lagrangian
stage, the start and the guideline clinician at equal env-step budgets, on fresh patients.

Rows: the guideline clinician (the expert); the safety-imitation start (BC with alpha 0.5, as
in ``improve_rehab.py``; the paired columns' reference here, the expert in
``selfimprove_rehab_vs_expert.py``, which shares these runs and evaluations); the
PPO-Lagrangian stage (shield + Lagrangian with ``improve_rehab.py``'s settings: the margin
sweep's cost margin 0.05 and shield zone 0.1) and self-imitation with the setting the rehab
selection table chose (:data:`SELF`; rehab pushes: intensity and duration +-0.05), each from
every seed's start.

Equal env-step budgets: every rehab episode is :data:`EPISODE_STEPS` sessions (steps), so equal
episodes are equal env steps. Self-imitation rolls out ``rounds x tracks_per_round x (1 +
pushes)`` training episodes (240 with the defaults: 7,200 env steps); the PPO-Lagrangian row
runs as many in :data:`EPISODES_PER_ITER`-episode iterations (15 x 16), a small fraction of
``improve_rehab.py``'s 384,000 steps, on purpose: the question is what each method makes of
the same interactions. Validation is matched in episodes as on CarRacing
(``selfimprove_carracing.py``): 3 x 32 patients each. The table records each run's env steps
(training rollouts and validation, counted the same way for both) and wall time (both in the
driver process, rollouts in-process), ``compare_history.parquet`` the learning curves.

3 training seeds x 200 fresh patients of held-out seed block 15, which no other table uses.

Run: ``safe-bc compare tune_jobs/compare/selfimprove_rehab.py``, then
``safe-bc compare tune_jobs/compare/selfimprove_rehab_vs_expert.py`` (evaluations reused).
Writes ``results/selfimprove/rehab/compare*``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import Comparison, Method, sibling
from safe_bc.selection import SelectionConfig
from safe_bc.selfimprove.config import SelfImproveConfig

EPISODE_STEPS = 30
"""Sessions per rehab episode (``safe_bc.tasks.rehab.env.DEFAULT_N_SESSIONS``)."""
EPISODES_PER_ITER = 16
"""PPO episodes (patients) per iteration."""
SELF = SelfImproveConfig()
"""The self-imitation row: the package's rehab defaults (2 rounds, kept rows in T_eps), the
setting the rehab selection table supports (``results/selfimprove/rehab/choice.md``: the
reliable gain over the start with the fewest programmes beyond d_s, 3 seeds x 200 selection
patients)."""
_car = sibling(__file__, "selfimprove_carracing")
EPISODES = _car.rollout_episodes(SELF, "rehab")
"""The shared training budget in episodes (240 with the defaults)."""
PPO = _car.ppo_at_budget(
    replace(sibling(__file__, "improve_rehab").BASE, shield=True, lagrangian=True),
    EPISODES,
    EPISODES_PER_ITER,
    _car.validation_budget(SELF, "rehab"),
    3,
)

COMPARISON = Comparison(
    name="compare",
    methods=(
        Method("expert", expert=True, label="guideline clinician (expert)"),
        Method(
            "imitation",
            selection=SelectionConfig(eps=0.05, alpha=0.5),
            label="safety-imitation start",
        ),
        Method("ppo_lagrangian", improve=PPO, start="imitation", label="PPO-Lagrangian + shield"),
        Method("selfimitation", selfimprove=SELF, start="imitation", label="self-imitation"),
    ),
    task="rehab",
    demos=Path("data/rehab_demos"),
    out=Path("results/selfimprove/rehab"),
    train_seeds=(0, 1, 2),
    episodes=200,
    eval_seed=15,
    workers=0,
    reference="imitation",
    paired_metrics=("reward", "violating_sessions"),
    totals=("any_violating_session", "last_session_violation", "violation_steps"),
    per_seed=True,
    figures=(("learning_curves", "compare_learning_curves.png"),),
    title="Self-imitation vs PPO-Lagrangian on the rehabilitation pathway, equal env-step budgets",
    note=f"Reward: capacity gain (points). Both improvements from the same starts with "
    f"{EPISODES * EPISODE_STEPS:,} training env steps per run. Paired rows: each agent against "
    "its own seed's start on the same patients. env steps / run: training rollouts; validation "
    "env steps / run: the episodes that pick (PPO) or accept (self-imitation) the final agent.",
)
