"""``BCPolicy``: a trained ``BCNet`` acting in an environment (a ``safe_bc.policy.Policy``)."""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from safe_bc.bc.checkpoint import load_checkpoint
from safe_bc.bc.config import PreprocessConfig
from safe_bc.bc.net import BCNet
from safe_bc.bc.preprocess import preprocess, stack
from safe_bc.policy import LockstepForward, check_lockstep_forward

if TYPE_CHECKING:
    import gymnasium as gym


class BCPolicy:
    """A trained ``BCNet`` as a ``safe_bc.policy.Policy`` (observations only, no privileges).

    ``act`` keeps the last ``frame_stack`` preprocessed frames of the current episode (the
    first frame repeated at the start, as in training); ``reset`` clears them.
    """

    def __init__(self, model: BCNet, pre_cfg: PreprocessConfig | None = None) -> None:
        self.model = model.eval()
        self.pre_cfg = model.pre_cfg if pre_cfg is None else pre_cfg
        if self.pre_cfg != model.pre_cfg:
            raise ValueError("pre_cfg differs from the one the model was built with")
        self._frames: deque[torch.Tensor] = deque(maxlen=self.pre_cfg.frame_stack)

    @classmethod
    def from_checkpoint(cls, directory: str | Path) -> BCPolicy:
        """Load a policy saved with ``safe_bc.bc.save_checkpoint``."""
        model, cfg = load_checkpoint(directory)
        return cls(model, cfg.preprocess)

    def reset(self, env: gym.Env | None = None, rng: np.random.Generator | None = None) -> None:
        """Start a new episode: forget the stacked frames."""
        self._frames.clear()

    def act(self, obs: np.ndarray, env: gym.Env | None = None) -> np.ndarray:
        """One observation ``(*obs_shape)`` -> action ``(A,) float32``."""
        obs = np.asarray(obs)
        if obs.shape != self.model.spec.obs_shape:
            raise ValueError(f"obs has shape {obs.shape}, expected {self.model.spec.obs_shape}")
        with torch.inference_mode():
            x = self._push(self._frames, preprocess(obs[None], self.pre_cfg))
            return self.model(x)[0].numpy().astype(np.float32, copy=False)

    @staticmethod
    def _push(frames: deque[torch.Tensor], frame: torch.Tensor) -> torch.Tensor:
        """Add one preprocessed ``(1, ...)`` frame to an episode's frames (the first one
        repeated ``frame_stack`` times) and return the net's ``(1, ...)`` input."""
        if frames.maxlen == 1:
            return frame
        frames.extend([frame] * (frames.maxlen if not frames else 1))
        return torch.cat(tuple(frames), dim=1)

    def reset_slots(self, n: int) -> None:
        """Start ``n`` episodes for :meth:`act_slots` (a ``safe_bc.policy.BatchPolicy``)."""
        self._slots: list[deque[torch.Tensor]] = [
            deque(maxlen=self.pre_cfg.frame_stack) for _ in range(n)
        ]

    def act_slots(
        self, obs: np.ndarray, slots: np.ndarray, forward: LockstepForward = "rows"
    ) -> np.ndarray:
        """One observation per episode in ``slots`` -> ``(m, A) float32``.

        ``forward="rows"``: bit for bit what :meth:`act` returns in each episode on any CPU
        (each row preprocessed and passed through the net on its own,
        :meth:`BCNet.forward_rows`). ``"batched"``: the ``m`` rows preprocessed together and
        one forward pass over them; the same actions again for the same inputs on the same
        machine, not necessarily :meth:`act`'s (``safe_bc.policy.LockstepForward``).
        """
        obs = np.asarray(obs)
        if obs.shape[1:] != self.model.spec.obs_shape:
            raise ValueError(
                f"obs has shape {obs.shape}, expected (m, *{self.model.spec.obs_shape})"
            )
        with torch.inference_mode():
            if forward == "rows":
                x = torch.cat([
                    self._push(self._slots[s], preprocess(obs[i : i + 1], self.pre_cfg))
                    for i, s in enumerate(slots)
                ])  # fmt: skip
                return self.model.forward_rows(x).numpy().astype(np.float32, copy=False)
            check_lockstep_forward(forward, "forward")
            x = preprocess(obs, self.pre_cfg)
            if self.pre_cfg.frame_stack > 1:
                x = torch.cat(
                    [self._push(self._slots[s], x[i : i + 1]) for i, s in enumerate(slots)]
                )
            return self.model(x).numpy().astype(np.float32, copy=False)

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Independent states -> actions ``(B, A) float32``; stateless.

        ``obs_batch`` is ``(B, *obs_shape)`` (with ``frame_stack > 1`` each frame is repeated,
        as at an episode's first step) or ``(B, k, *obs_shape)`` stacks, oldest first.
        """
        obs_batch = np.asarray(obs_batch)
        shape, k = self.model.spec.obs_shape, self.pre_cfg.frame_stack
        if obs_batch.shape[1:] == shape:
            obs_batch = np.repeat(obs_batch[:, None], k, axis=1)
        elif obs_batch.shape[1:] != (k, *shape):
            raise ValueError(
                f"obs_batch has shape {obs_batch.shape}, "
                f"expected (B, *{shape}) or (B, {k}, *{shape})"
            )
        flat = obs_batch.reshape(-1, *shape)
        with torch.inference_mode():
            x = stack(preprocess(flat, self.pre_cfg), k)
            return self.model(x).numpy().astype(np.float32, copy=False)
