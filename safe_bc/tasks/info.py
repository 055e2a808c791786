"""The ``info`` contract every task's env meets, as a typed, checked record.

Each ``reset`` and ``step`` of an env built by :func:`safe_bc.tasks.make_env` describes the
returned observation in ``info`` with (``S`` = the env's ``safety_dims``):

* ``"safety"``: ``(S,)`` finite floats, distances to the limits, higher is safer;
* ``"cost"``: ``(S,)`` finite floats, higher is less safe;
* ``"warmup"``: ``bool``, a step not to be scored (CarRacing's zoom-in);
* ``"offroad"``: ``bool``, ground truth of a safety failure (evaluation only).

The env (or a wrapper) publishes ``safety_dims``, the names of the ``S`` dimensions.
:class:`InfoContract` checks the first infos of every episode (``reset`` and the first
step: the shapes and types do not change later), so a task that breaks the contract fails
on its first episode with one line naming the key, not deep inside collection.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

INFO_KEYS: tuple[str, ...] = ("safety", "cost", "warmup", "offroad")
"""The keys :func:`check_info` requires."""


@dataclass(frozen=True)
class StepInfo:
    """The contract's part of one ``info``, checked."""

    safety: np.ndarray
    """``(S,) float`` distances to the limits, higher is safer."""
    cost: np.ndarray
    """``(S,) float`` costs, higher is less safe."""
    warmup: bool
    """An unscored step."""
    offroad: bool
    """Ground-truth safety failure (evaluation only)."""


def _flag(info: dict[str, Any], key: str) -> bool:
    value = info[key]
    if not isinstance(value, bool | np.bool_):
        raise ValueError(f"info[{key!r}] must be a bool, got {type(value).__name__}")
    return bool(value)


def _vector(info: dict[str, Any], key: str, dims: int) -> np.ndarray:
    value = np.asarray(info[key])
    if value.shape != (dims,) or not np.issubdtype(value.dtype, np.floating):
        raise ValueError(
            f"info[{key!r}] must be ({dims},) floats (one per safety dim), "
            f"got {value.dtype} {value.shape}"
        )
    if not np.all(np.isfinite(value)):
        raise ValueError(f"info[{key!r}] must be finite, got {value}")
    return value


def check_info(info: dict[str, Any], safety_dims: tuple[str, ...]) -> StepInfo:
    """The contract's record of ``info``; raises ``ValueError`` naming the first broken key.

    >>> check_info({"safety": np.ones(1), "cost": np.zeros(1), "warmup": False,
    ...             "offroad": False}, ("gap",)).warmup
    False
    """
    missing = [k for k in INFO_KEYS if k not in info]
    if missing:
        raise ValueError(f"info lacks {missing} (the contract: {', '.join(INFO_KEYS)})")
    dims = len(safety_dims)
    return StepInfo(
        safety=_vector(info, "safety", dims),
        cost=_vector(info, "cost", dims),
        warmup=_flag(info, "warmup"),
        offroad=_flag(info, "offroad"),
    )


class InfoContract(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Check the ``info`` of each episode's ``reset`` and first ``step``
    (:func:`check_info`); every other call passes straight through. (Recorded in the env's
    spec, so an env rebuilt from it, e.g. a Minari dataset's, is checked too.)"""

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        try:
            self._dims = tuple(env.get_wrapper_attr("safety_dims"))
        except AttributeError:
            raise ValueError(
                f"{env.spec.id if env.spec else env}: publishes no safety_dims "
                "(the info contract, safe_bc.tasks.info)"
            ) from None
        self._check_next = False

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        check_info(info, self._dims)
        self._check_next = True
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        out = self.env.step(action)
        if self._check_next:
            self._check_next = False
            check_info(out[4], self._dims)
        return out
