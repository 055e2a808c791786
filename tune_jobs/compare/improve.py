"""Beyond the expert: constrained improvement (PPO, shield, Lagrangian) from BC starts.

* ``improve_carracing``: the expert; the safety-imitation start (BC with alpha 0.1, eps 2 px,
  the default network and budget; the paired columns' reference); one
  :func:`safe_bc.methods.improve.improve` run per mode from each seed's start (``ppo``: neither
  mechanism, ``shield``, ``lagrangian``, ``both``), sized for pixels on small machines
  (:data:`CARRACING`: 4 complete 1000-step episodes per PPO iteration, 20 iterations,
  validation on 4 tracks every 5 iterations, a cost margin of 1 px inside d_s). 3 training
  seeds x 50 held-out tracks of block 7. ``improve_history.parquet`` holds the learning curves.
* ``improve_carracing_std003``: shield + Lagrangian with a smaller initial action noise
  (``init_std`` 0.03), 20 held-out tracks of block 10 (the observation tables' selection
  block: declared below).
* ``fallback``: a diagnostic over ``improve_carracing``'s nets (its runs folder, nothing
  retrained): the start, PPO and shield + Lagrangian with the scripted expert acting in their
  critical states (privileged: a bound on what a safe fallback would give, not a deployable
  CarRacing policy); its tables (``fallback*``) beside ``improve_carracing``'s.
* ``improve_rehab``: the guideline clinician (the reference, standing in for every training
  seed on the same patients); the safety-imitation start (BC with alpha 0.5); one run per mode
  (``shield``, ``lagrangian``, ``both``) with the rehab defaults and a shield zone of
  :data:`SHIELD_EPS`. 3 training seeds x 200 held-out patients of block 5. The evaluation
  counts the sessions whose outcome went beyond d_s, the last one included
  (``violating_sessions``, ``any_violating_session``, ``last_session_violation``).

Row names are the keys of the committed tables, which seed the bootstrap. Run: ``safe-bc
compare tune_jobs/compare/improve.py --name NAME`` (resumes per method and seed). Writes
``improve*.parquet``, ``improve.md`` and ``learning_curves.png`` (``fallback*`` for the
diagnostic) under each comparison's folder.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare.spec import Agent, Comparison, Expert, FromStart, Handover, Row
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.selection import SelectionConfig

CARRACING = ImproveConfig(
    iterations=20,
    episodes_per_iter=4,
    n_envs=4,
    eval_every=5,
    eval_episodes=4,
    cost_margin=1.0,
    checkpoint_every=1,
)
"""CarRacing's improvement runs, sized for pixels."""
SHIELD_EPS = 0.1
"""Width of the shield's critical zone on the rehab pathway (``ImproveConfig.eps``): the margin
sweep's choice, shield + Lagrangian with ``cost_margin`` 0.05 and this zone
(``results/improve/rehab/sweep/margin_sweep.md``)."""
REHAB = ImproveConfig(eps=SHIELD_EPS)
"""The rehab runs: the task's defaults and the shield zone."""
MODES = {  # name: (label, shield, lagrangian)
    "ppo": ("PPO, neither mechanism", False, False),
    "shield": ("shield only", True, False),
    "lagrangian": ("Lagrangian only", False, True),
    "both": ("shield + Lagrangian", True, True),
}
"""The improvement modes: which of the two safety mechanisms a run uses."""


def modes(base: ImproveConfig, names: tuple[str, ...]) -> tuple[Row, ...]:
    """One improvement row per mode of ``names``, from the ``imitation`` row."""
    return tuple(
        FromStart(n, "imitation", replace(base, shield=MODES[n][1], lagrangian=MODES[n][2]),
                  label=MODES[n][0])
        for n in names
    )  # fmt: skip


CAR_EXPERT = Expert("expert", label="expert (scripted, privileged)")
CAR_START = Agent("imitation", SelectionConfig(eps=2.0, alpha=0.1),
                  label="safety-imitation start (alpha 0.1)")  # fmt: skip
CAR = Comparison(
    name="improve",
    methods=(CAR_EXPERT, CAR_START, *modes(CARRACING, ("ppo", "shield", "lagrangian", "both"))),
    task="carracing",
    out=Path("results/improve/carracing"),
    train_seeds=(0, 1, 2),
    episodes=50,
    eval_seed=7,
    reference="imitation",
    paired_metrics=("reward", "violation_steps"),
    per_seed=True,
    figures=(("learning_curves", "learning_curves.png"),),
    title="Beyond the expert: constrained improvement on CarRacing",
    note="Paired rows: each improved agent against its own seed's start on the same tracks. "
    "minutes / run: wall time of one improvement run (rollouts, PPO updates, validation).",
)
"""``improve_carracing``."""
FALLBACK = ("imitation", "both", "ppo")
"""``fallback``'s rows evaluated with the expert as their fallback."""

COMPARISONS = {
    "improve_carracing": CAR,
    "improve_carracing_std003": replace(
        CAR,
        methods=(CAR_EXPERT, CAR_START, *modes(replace(CARRACING, init_std=0.03), ("both",))),
        out=Path("results/improve/carracing_std003"),
        episodes=20,
        eval_seed=10,
        title="Constrained improvement on CarRacing, initial action noise 0.03",
        shares_tracks_with=tuple(
            f"results/ablation/{n}/{n}"
            for n in ("observation", "batch", "budget", "network", "resize")
        ),
    ),
    "fallback": replace(
        CAR,
        name="fallback",
        runs="improve",
        methods=(
            *(m for m in CAR.methods if m.name in {"expert", *FALLBACK}),
            *(
                Handover(f"{n}+expert", n, label=f"{n}, expert in critical states")
                for n in FALLBACK
            ),
        ),
        paired_metrics=("reward", "violation_steps"),
        per_seed=False,
        figures=(),
        title="Diagnostic: the expert as the shield's fallback (CarRacing)",
        note="Rows +expert: the same nets, the scripted expert (privileged) acting in their "
        "critical states; a bound on what a safe fallback would give, not a deployable policy.",
    ),
    "improve_rehab": Comparison(
        name="improve",
        methods=(
            Expert("expert", label="guideline clinician (expert)"),
            Agent(
                "imitation", SelectionConfig(eps=0.05, alpha=0.5), label="safety-imitation start"
            ),
            *modes(REHAB, ("shield", "lagrangian", "both")),
        ),
        task="rehab",
        demos=Path("data/rehab_demos"),
        out=Path("results/improve/rehab"),
        train_seeds=(0, 1, 2),
        episodes=200,
        eval_seed=5,
        workers=0,
        reference="expert",
        paired_metrics=("reward", "violating_sessions"),
        totals=("any_violating_session", "last_session_violation", "violation_steps"),
        figures=(("learning_curves", "learning_curves.png"),),
        title="Beyond the expert: constrained improvement on the rehabilitation pathway",
        note="Reward: capacity gain (points). minutes / run: wall time of one improvement run.",
        shares_tracks_with=("results/improve/rehab/sweep/sweep_test",),
    ),
}
