"""Frozen record of one rollout: what the data store writes and training reads.

Step ``t`` pairs the observation ``s_t`` with the action chosen in it, and the
safety of ``s_t``; ``reward[t]``, ``terminated[t]`` and ``truncated[t]`` are what
the environment returned after executing ``executed_action[t]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SAFETY_DIMS: tuple[str, ...] = ("left", "front", "right")
"""CarRacing's safety dimensions, in column order of ``safety`` and ``cost`` (the default)."""


@dataclass(frozen=True)
class Episode:
    """One episode of ``T`` steps.

    Attributes:
        episode_id: Position of the episode in its collection (0-based).
        seed: Track / patient seed passed to ``env.reset(seed=...)``.
        observations: ``(T, *obs_shape)``; ``(T, 96, 96, 3) uint8`` for CarRacing,
            ``(T, D) float32`` for vector environments.
        actions: ``(T, A) float32``, the action the policy (expert) chose.
        executed_actions: ``(T, A) float32``, the action sent to the env (differs
            from ``actions`` only under perturbation).
        rewards: ``(T,) float32``.
        terminated: ``(T,) bool``.
        truncated: ``(T,) bool``.
        safety: ``(T, S) float32``, safety distances (higher is safer).
        costs: ``(T, S) float32``, safety costs (higher is less safe).
        warmup: ``(T,) bool``, steps whose frame is not scored (CarRacing zoom-in).
        offroad: ``(T,) bool``, all wheels off the road (the unsafe event).
        safety_dims: names of the ``S`` safety dimensions.
        final_cost: ``(S,) float32``, the cost of the state the last step led to (the
            outcome of the last action, which no later step records); ``None`` where the
            episode was not recorded by a rollout (e.g. read back from the data store).
    """

    episode_id: int
    seed: int
    observations: np.ndarray
    actions: np.ndarray
    executed_actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    safety: np.ndarray
    costs: np.ndarray
    warmup: np.ndarray
    offroad: np.ndarray
    safety_dims: tuple[str, ...] = field(default=SAFETY_DIMS)
    final_cost: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.observations)
        for name in (
            "actions",
            "executed_actions",
            "rewards",
            "terminated",
            "truncated",
            "safety",
            "costs",
            "warmup",
            "offroad",
        ):
            if len(getattr(self, name)) != n:
                raise ValueError(
                    f"Episode field {name!r} has {len(getattr(self, name))} rows, "
                    f"observations have {n}"
                )
        if self.safety.shape[1:] != (len(self.safety_dims),):
            raise ValueError(
                f"safety has shape {self.safety.shape}, expected (T, {len(self.safety_dims)})"
            )

    def __len__(self) -> int:
        return len(self.observations)

    @property
    def total_reward(self) -> float:
        """Sum of rewards over the episode."""
        return float(np.sum(self.rewards, dtype=np.float64))
