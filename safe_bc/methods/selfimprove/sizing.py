"""Sizes of self-imitation runs: their env-step budgets, a PPO run resized to the same budget,
and pushes of half the size (pure, no env)."""

from __future__ import annotations

from dataclasses import replace

from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.methods.selfimprove.config import SelfImproveConfig, parse_push


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
    validated ``validations`` times (evenly) on ``validation_episodes`` episodes in all.

    Raises:
        ValueError: the episodes do not split that way.
    """
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


def half(spec: str) -> str:
    """A push of half the size: offsets halved, scales halfway to 1.

    >>> [half(s) for s in ("1+0.03", "2*0.8", "0-0.1")]
    ['1+0.015', '2*0.9', '0-0.05']
    """
    terms = []
    for dim, op, value in parse_push(spec):
        terms.append(f"{dim}*{1 - (1 - value) / 2:g}" if op == "*" else f"{dim}{value / 2:+g}")
    return ",".join(terms)
