"""Self-imitation on CarRacing against the PPO-Lagrangian stage, the start and
the expert at equal env-step budgets, on fresh tracks.

Rows: the expert; the safety-imitation start (BC with alpha 0.1 on T_eps, as in
``improve_carracing.py``; the paired columns' reference here, the expert in
``selfimprove_carracing_vs_expert.py``, which shares these runs and evaluations); the
PPO-Lagrangian stage (shield + Lagrangian, :data:`safe_bc.improve.config.ImproveConfig`
defaults as the study's improve stage runs them, with ``improve_carracing.py``'s sizing for
pixels: 4 episodes per iteration, cost margin 1 px) and self-imitation with the setting the
CarRacing rounds table chose (:data:`SELF`: 4 rounds of half-size pushes,
``results/selfimprove/carracing/rounds_choice.md``), each from every seed's start.

Equal env-step budgets: CarRacing episodes last at most :data:`EPISODE_STEPS` steps (fewer when
the car leaves the playfield), so a budget is set in episodes. Self-imitation rolls out
``rounds x tracks_per_round x (1 + pushes)`` training episodes (:func:`rollout_episodes`; 576 for
:data:`SELF`: at most 576,000 env steps); the PPO-Lagrangian row runs as many in
``iterations x episodes_per_iter`` (144 x 4), so both are capped by the same env steps. The
validation episodes that pick or accept the final agent are matched too: self-imitation
validates the start and every round on 32 tracks (5 x 32 = 160 episodes), PPO every
``iterations / 4`` iterations on 40 (4 x 40 = 160). (The first run of this file, at 288
episodes with the 2-round defaults, is in the git history of ``results/selfimprove/carracing``.)
The table records each run's actual env steps (``env steps / run``: training rollouts,
counted the same way for both; ``validation env steps / run``) and wall time (``minutes /
run``; both run in the driver process, one after the other, rollouts in-process:
``workers=0``), and ``compare_history.parquet`` the learning curves (PPO per iteration,
self-imitation per round).

3 training seeds x 50 fresh tracks of held-out seed block 14, which no other table uses (the
selection tracks that chose the defaults are block 13, ``selfimprove_selection_carracing.py``).

Run: ``safe-bc compare tune_jobs/compare/selfimprove_carracing.py``, then
``safe-bc compare tune_jobs/compare/selfimprove_carracing_vs_expert.py`` (evaluations reused).
Writes ``results/selfimprove/carracing/compare*``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import Comparison, Method, sibling
from safe_bc.improve.config import ImproveConfig
from safe_bc.selection import SelectionConfig
from safe_bc.selfimprove.config import SelfImproveConfig

EPISODE_STEPS = 1000
"""CarRacing's time limit (steps per episode at most)."""
EPISODES_PER_ITER = 4
"""PPO episodes per iteration (``improve_carracing.py``'s sizing for pixels)."""
PPO_VALIDATIONS = 4
"""PPO validations per run (every ``iterations / 4`` iterations; 144 iterations do not split
into self-imitation's 5), each on ``validation_budget(SELF) / 4`` tracks."""
SELF = SelfImproveConfig()
"""The self-imitation row: the package's CarRacing defaults, the rounds table's choice (4
rounds, pushes of half the size; ``results/selfimprove/carracing/rounds_choice.md``, 3 seeds x
50 selection tracks of block 13), rolled out in the driver process like the PPO row."""


def rollout_episodes(config: SelfImproveConfig, task: str) -> int:
    """Training episodes of a self-imitation run: each round runs every track unperturbed and
    once per push."""
    c = config.for_task(task)
    assert c.rounds is not None and c.pushes is not None
    return c.rounds * c.tracks_per_round * (1 + len(c.pushes))


def validation_budget(config: SelfImproveConfig, task: str) -> int:
    """Validation episodes of a self-imitation run: the start and every round."""
    rounds = config.for_task(task).rounds
    assert rounds is not None
    return (rounds + 1) * config.validation_episodes


def ppo_at_budget(
    base: ImproveConfig, episodes: int, per_iter: int, validation_episodes: int, validations: int
) -> ImproveConfig:
    """``base`` resized to ``episodes`` training episodes in ``per_iter``-episode iterations,
    validated ``validations`` times (evenly) on ``validation_episodes`` episodes in all."""
    if episodes % (per_iter * validations) or validation_episodes % validations:
        raise ValueError(
            f"{episodes} episodes in {per_iter}-episode iterations and {validation_episodes} "
            f"validation episodes do not split into {validations} validations"
        )
    iterations = episodes // per_iter
    return replace(
        base, iterations=iterations, episodes_per_iter=per_iter, n_envs=per_iter,
        eval_every=iterations // validations, eval_episodes=validation_episodes // validations,
    )  # fmt: skip


EPISODES = rollout_episodes(SELF, "carracing")
"""The shared training budget in episodes (576 for :data:`SELF`)."""
PPO = ppo_at_budget(
    replace(sibling(__file__, "improve_carracing").BASE, shield=True, lagrangian=True),
    EPISODES,
    EPISODES_PER_ITER,
    validation_budget(SELF, "carracing"),
    PPO_VALIDATIONS,
)
START = SelectionConfig(eps=2.0, alpha=0.1)

COMPARISON = Comparison(
    name="compare",
    methods=(
        Method("expert", expert=True, label="expert (scripted, privileged)"),
        Method("imitation", selection=START, label="safety-imitation start (alpha 0.1)"),
        Method("ppo_lagrangian", improve=PPO, start="imitation", label="PPO-Lagrangian + shield"),
        Method(
            "selfimitation",
            selfimprove=SELF,
            start="imitation",
            label="self-imitation (4 rounds, half-size pushes)",
        ),
    ),
    task="carracing",
    out=Path("results/selfimprove/carracing"),
    train_seeds=(0, 1, 2),
    episodes=50,
    eval_seed=14,
    reference="imitation",
    paired_metrics=("reward", "violation_steps"),
    totals=("any_violation",),
    per_seed=True,
    figures=(("learning_curves", "compare_learning_curves.png"),),
    title="Self-imitation vs PPO-Lagrangian on CarRacing, equal env-step budgets",
    note=f"Both improvements from the same starts with at most {EPISODES * EPISODE_STEPS:,} "
    "training env steps per run. Paired rows: each agent against its own seed's start on the "
    "same fresh tracks. env steps / run: training rollouts; validation env steps / run: the "
    "episodes that pick (PPO) or accept (self-imitation) the final agent.",
)
