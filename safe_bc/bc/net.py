"""The BC network: ``ModelSpec`` (what the data fixes) and ``BCNet`` (frames or vectors ->
bounded actions)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from safe_bc.bc.config import NetworkConfig, PreprocessConfig
from safe_bc.bc.preprocess import input_shape, is_image

CAR_RACING_BOUNDS: tuple[tuple[float, ...], tuple[float, ...]] = ((-1.0, 0.0, 0.0), (1.0, 1.0, 1.0))
"""``(low, high)`` of CarRacing's ``(steer, gas, brake)``."""


@dataclass(frozen=True)
class ModelSpec:
    """What the data fixes about a ``BCNet`` (as opposed to its hyper-parameters).

    Attributes:
        obs_shape: one raw observation, ``(96, 96, 3)`` or ``(D,)``.
        action_low: ``(A,)`` lower bounds, ``-inf`` for unbounded.
        action_high: ``(A,)`` upper bounds, ``inf`` for unbounded.
    """

    obs_shape: tuple[int, ...]
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "obs_shape", tuple(int(x) for x in self.obs_shape))
        low = tuple(-math.inf if x is None else float(x) for x in self.action_low)
        high = tuple(math.inf if x is None else float(x) for x in self.action_high)
        object.__setattr__(self, "action_low", low)
        object.__setattr__(self, "action_high", high)
        if len(low) != len(high) or not low:
            raise ValueError(f"action bounds disagree or are empty: low={low} high={high}")
        if any(not lo < hi for lo, hi in zip(low, high, strict=True)):
            raise ValueError(f"need low < high per action dimension: low={low} high={high}")

    @property
    def action_dim(self) -> int:
        return len(self.action_low)

    @classmethod
    def for_data(
        cls,
        obs_shape: Sequence[int],
        action_dim: int,
        bounds: tuple[Sequence[float], Sequence[float]] | None = None,
    ) -> ModelSpec:
        """Spec with explicit ``bounds``, else CarRacing's for 3-d actions on frames, else
        unbounded."""
        if bounds is None:
            if is_image(obs_shape) and action_dim == 3:
                bounds = CAR_RACING_BOUNDS
            else:
                bounds = ((-math.inf,) * action_dim, (math.inf,) * action_dim)
        spec = cls(tuple(obs_shape), tuple(bounds[0]), tuple(bounds[1]))
        if spec.action_dim != action_dim:
            raise ValueError(f"bounds have {spec.action_dim} dimensions, actions {action_dim}")
        return spec

    def to_dict(self) -> dict[str, Any]:
        """Strict-JSON dict: infinite bounds become ``None``."""
        return {
            "obs_shape": list(self.obs_shape),
            "action_low": [None if math.isinf(x) else x for x in self.action_low],
            "action_high": [None if math.isinf(x) else x for x in self.action_high],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelSpec:
        return cls(tuple(data["obs_shape"]), tuple(data["action_low"]), tuple(data["action_high"]))


def resolve_kind(kind: str, obs_shape: Sequence[int]) -> str:
    """``"auto"`` -> ``"cnn"`` for frames, ``"mlp"`` for vectors; a CNN needs frames."""
    if kind == "auto":
        return "cnn" if is_image(obs_shape) else "mlp"
    if kind == "cnn" and not is_image(obs_shape):
        raise ValueError(f"a CNN needs (H, W, 3) frames, observations are {tuple(obs_shape)}")
    return kind


def _mlp(n_in: int, hidden: int, layers: int, n_out: int) -> nn.Sequential:
    mods: list[nn.Module] = []
    for _ in range(layers):
        mods += [nn.Linear(n_in, hidden), nn.ReLU()]
        n_in = hidden
    mods.append(nn.Linear(n_in, n_out))
    return nn.Sequential(*mods)


class BCNet(nn.Module):
    """Preprocessed observations ``(B, *input_shape)`` -> bounded actions ``(B, A)``.

    Frames go through a conv stack (``Conv-ReLU`` per entry of ``channels``) and an MLP head;
    vectors are standardised (buffers ``obs_mean``/``obs_std``, saved with the weights) and go
    through an MLP. Each action dimension is squashed to its bounds: ``high * tanh(z)`` for
    symmetric bounds (steer), ``low + (high - low) * sigmoid(z)`` for other finite bounds
    (gas, brake), ``z`` when unbounded (either side infinite).
    """

    def __init__(self, spec: ModelSpec, pre_cfg: PreprocessConfig, net_cfg: NetworkConfig):
        super().__init__()
        self.spec, self.pre_cfg, self.net_cfg = spec, pre_cfg, net_cfg
        self.kind = resolve_kind(net_cfg.kind, spec.obs_shape)
        self.input_shape = input_shape(spec.obs_shape, pre_cfg)
        self.vector_input = not is_image(spec.obs_shape)

        if self.kind == "cnn":
            convs: list[nn.Module] = []
            c_in = self.input_shape[0]
            for c_out, k, s in zip(
                net_cfg.channels, net_cfg.kernel_sizes, net_cfg.strides, strict=True
            ):
                convs += [nn.Conv2d(c_in, c_out, k, s), nn.ReLU()]
                c_in = c_out
            self.body = nn.Sequential(*convs, nn.Flatten())
            try:
                with torch.no_grad():
                    n_flat = self.body(torch.zeros(1, *self.input_shape)).shape[1]
            except RuntimeError as e:
                raise ValueError(
                    f"input {self.input_shape} too small for conv kernels "
                    f"{net_cfg.kernel_sizes} / strides {net_cfg.strides}: {e}"
                ) from e
        else:
            self.body = nn.Sequential(nn.Flatten())
            n_flat = math.prod(self.input_shape)
        self.head = _mlp(n_flat, net_cfg.hidden, net_cfg.mlp_layers, spec.action_dim)

        n_feat = self.input_shape[0] if self.vector_input else 0
        self.register_buffer("obs_mean", torch.zeros(n_feat))
        self.register_buffer("obs_std", torch.ones(n_feat))

        low = torch.tensor(spec.action_low, dtype=torch.float64)
        high = torch.tensor(spec.action_high, dtype=torch.float64)
        finite = low.isfinite() & high.isfinite()
        tanh_m = finite & (low == -high)
        sig_m = finite & ~tanh_m
        zero = torch.zeros_like(low)
        for name, value in {
            "_tanh_mask": tanh_m,
            "_sig_mask": sig_m,
            "_id_mask": ~finite,
            "_tanh_scale": torch.where(tanh_m, high, zero),
            "_sig_low": torch.where(sig_m, low, zero),
            "_sig_span": torch.where(sig_m, high - low, zero),
        }.items():
            self.register_buffer(name, value.to(torch.float32), persistent=False)

    def set_standardization(self, mean: np.ndarray, std: np.ndarray) -> None:
        """Set the per-feature ``(D_in,)`` input statistics (vector input only)."""
        if not self.vector_input:
            raise ValueError("standardization applies to vector observations only")
        mean_t = torch.as_tensor(mean, dtype=torch.float32)
        std_t = torch.as_tensor(std, dtype=torch.float32)
        if mean_t.shape != self.obs_mean.shape or std_t.shape != self.obs_std.shape:
            raise ValueError(f"stats must have shape {tuple(self.obs_mean.shape)}")
        if not (std_t > 0).all():
            raise ValueError("std must be > 0")
        self.obs_mean.copy_(mean_t)
        self.obs_std.copy_(std_t)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, *input_shape) float32 -> (B, A) float32``."""
        if self.vector_input:
            x = (x - self.obs_mean) / self.obs_std
        return self._squash(self.head(self.body(x)))

    def forward_rows(self, x: torch.Tensor) -> torch.Tensor:
        """``forward`` of each row on its own: equal, bit for bit, to ``B`` one-row passes on
        every machine, by construction (it *is* ``B`` one-row passes).

        A batched pass may round differently from a 1-row one: torch (oneDNN, MKL, ATen's
        vectorised loops) picks kernels by shape and by the CPU's instruction set, so which
        layers are batch-invariant differs between CPUs (on an AVX-512 EPYC a probe on random
        input said 7 of 7 layers for batches of 2 and 3, 4 of 7 for 4, and real frames still
        rounded differently). No layer is assumed invariant, so the lockstep evaluation gives
        the one-env path's episodes wherever it runs; what batching costs is measured by
        ``make bench`` (eval case).
        """
        return torch.cat([self(x[i : i + 1]) for i in range(len(x))])

    def _squash(self, z: torch.Tensor) -> torch.Tensor:
        return (
            self._tanh_mask * self._tanh_scale * torch.tanh(z)
            + self._sig_mask * (self._sig_low + self._sig_span * torch.sigmoid(z))
            + self._id_mask * z
        )
