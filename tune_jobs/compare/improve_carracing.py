"""Beyond the expert on CarRacing: constrained improvement from pixels, 3 seeds x 4 modes.

Rows: the expert; the safety-imitation start (BC with alpha 0.1, the best alpha row of the
Table 1 made with the cropped bar; the default network and budget; the paired columns'
reference); one :func:`safe_bc.improve.improve` run per mode from each seed's start (``ppo``:
neither mechanism, ``shield``, ``lagrangian``, ``both``), sized for pixels on small
machines: 4 complete 1000-step episodes per PPO iteration, 20 iterations, validation on 4
tracks every 5 iterations, a cost margin of 1 px inside d_s. Every policy on the same 50
fresh held-out tracks (seed block 7, used by no other table). Row names are the keys of the
committed tables (``results/improve/carracing/episodes.parquet``), which seed the bootstrap;
``tests/test_compare_improve.py`` re-derives their summary through this spec.

Run: ``safe-bc compare tune_jobs/compare/improve_carracing.py`` (hours on 2 cores; every
start, run and evaluation resumes per method and seed). Writes
``results/improve/carracing/improve*.parquet`` (``improve_history.parquet``: the learning
curves), ``improve.md`` and ``learning_curves.png``. Another start: edit ``START_ALPHA``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import Comparison, Method
from safe_bc.improve.config import ImproveConfig
from safe_bc.selection import SelectionConfig

START_ALPHA = 0.1
"""Safety focus of the starts."""
BASE = ImproveConfig(
    iterations=20,
    episodes_per_iter=4,
    n_envs=4,
    eval_every=5,
    eval_episodes=4,
    cost_margin=1.0,
    checkpoint_every=1,
)
MODES = {  # name: (label, shield, lagrangian)
    "ppo": ("PPO, neither mechanism", False, False),
    "shield": ("shield only", True, False),
    "lagrangian": ("Lagrangian only", False, True),
    "both": ("shield + Lagrangian", True, True),
}


def methods(base: ImproveConfig, modes: dict[str, tuple[str, bool, bool]]) -> tuple[Method, ...]:
    """The expert, the start and one improvement row per mode."""
    return (
        Method("expert", expert=True, label="expert (scripted, privileged)"),
        Method(
            "imitation",
            selection=SelectionConfig(eps=2.0, alpha=START_ALPHA),
            label=f"safety-imitation start (alpha {START_ALPHA})",
        ),
        *(
            Method(
                name,
                improve=replace(base, shield=shield, lagrangian=lagrangian),
                start="imitation",
                label=label,
            )
            for name, (label, shield, lagrangian) in modes.items()
        ),
    )


COMPARISON = Comparison(
    name="improve",
    methods=methods(BASE, MODES),
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
