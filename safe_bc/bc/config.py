"""Frozen hyper-parameter records for behaviour cloning (JSON round-trippable)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Literal, get_args

NetKind = Literal["auto", "cnn", "mlp"]


def _positive_int(name: str, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {name}={value!r}")


@dataclass(frozen=True)
class PreprocessConfig:
    """Observation -> network input. Image options only apply to ``(H, W, 3) uint8`` frames.

    The image defaults (colour, the indicator bar kept with its steering indicator masked,
    one frame) are the observation ablation's choice: ``results/ablation/observation/``
    (``tune_jobs/compare/observation.py``; plain BC, 3 training seeds x 20 selection
    tracks per cell). Until then they were grey, bar cropped: agents blind to their speed."""

    grayscale: bool = False
    """Collapse RGB to one luma channel (ITU-R 601 weights). Off by default: with the bar kept,
    colour agents crossed d_s in 1 of 60 episodes each, grey ones in 9-13 (the ablation)."""

    crop_bar: bool = False
    """Drop the bottom 12 rows (rows 84-95 of CarRacing: the speed/ABS/steering indicator bar).
    Off by default: the bar is the only place a single frame shows the car's speed; cropping
    it cost ~470 reward and ~210 steps beyond d_s per episode (the ablation)."""

    mask_steering: bool = True
    """Paint the steering-angle indicator of a CarRacing frame black (rows 84-95, columns
    36-61: ``preprocess.STEERING_INDICATOR``) before anything else, keeping the rest of the
    bar (speed, ABS, gyro); only meaningful with ``crop_bar=False`` and 96x96 frames. Against
    copycat behaviour: the indicator shows the steering the agent just chose. On by default:
    the ablation's rule picks it among the colour cells that crossed d_s in 1 of 60 episodes
    each, on reward (not a reliable difference)."""

    frame_stack: int = 1
    """Number of consecutive frames (oldest first) stacked along channels (features for
    vectors); at an episode's first steps the first frame is repeated."""

    resize: int | None = None
    """Resize (area interpolation) the cropped frame to ``resize x resize``; ``None`` keeps it."""

    standardize: bool = True
    """Vectors only: standardise features with the training set's mean/std (kept in the model)."""

    def __post_init__(self) -> None:
        _positive_int("frame_stack", self.frame_stack)
        if self.resize is not None:
            _positive_int("resize", self.resize)
            if self.resize < 4:
                raise ValueError(f"resize must be >= 4 or None, got resize={self.resize!r}")


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture of ``BCNet``."""

    kind: NetKind = "auto"
    """``"cnn"`` for frames, ``"mlp"`` for vectors (or flattened frames); ``"auto"`` picks
    from the observation shape."""

    channels: tuple[int, ...] = (16, 32, 32)
    """Output channels of the conv layers (CNN only); may be empty (head on raw pixels).
    The default was measured against 8-16-16 and 32-64-64 (``results/ablation/network/``,
    plain BC, 3 training seeds x 20 selection tracks): 8-16-16 is reliably worse; 32-64-64 is
    not reliably different in reward or crossings (its table's rule names it by one episode
    of 60; ``docs/defaults.md`` says why the default stays)."""

    kernel_sizes: tuple[int, ...] = (8, 4, 3)
    """Square kernel of each conv layer (CNN only), one per entry of ``channels`` (a single
    entry is used for every layer)."""

    strides: tuple[int, ...] = (4, 2, 1)
    """Stride of each conv layer (CNN only; a single entry is used for every layer); no
    padding. The default (8/4, 4/2, 3/1) is the DQN stack: about 3.0 M multiply-adds per
    96x96 colour frame (1.7 M per 84x96 grey one), cheap enough for CPU training; kernels
    and strides were not measured against alternatives."""

    hidden: int = 128
    """Width of the hidden layers of the MLP head / MLP."""

    mlp_layers: int = 2
    """Number of hidden layers of the MLP head (CNN) or of the MLP (vectors)."""

    def __post_init__(self) -> None:
        if self.kind not in get_args(NetKind):
            raise ValueError(f"kind must be one of {get_args(NetKind)}, got kind={self.kind!r}")
        for name in ("channels", "kernel_sizes", "strides"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
            for v in getattr(self, name):
                _positive_int(f"{name}[i]", v)
        for name in ("kernel_sizes", "strides"):  # one entry applies to every layer
            value = getattr(self, name)
            if not self.channels or len(value) == 1:
                object.__setattr__(self, name, value[:1] * len(self.channels))
        if not len(self.channels) == len(self.kernel_sizes) == len(self.strides):
            raise ValueError(
                f"channels, kernel_sizes and strides need equal lengths, got {self.channels}, "
                f"{self.kernel_sizes}, {self.strides}"
            )
        _positive_int("hidden", self.hidden)
        if isinstance(self.mlp_layers, bool) or not isinstance(self.mlp_layers, int):
            raise ValueError(f"mlp_layers must be an integer >= 0, got {self.mlp_layers!r}")
        if self.mlp_layers < 0:
            raise ValueError(f"mlp_layers must be >= 0, got mlp_layers={self.mlp_layers!r}")


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation of the BC regression (CPU, deterministic)."""

    batches: int = 2000
    """Number of gradient steps (the paper's budget is 2000 batches)."""

    batch_size: int = 64
    """State-action pairs per batch (must equal the sampler's)."""

    lr: float = 3e-4
    """Adam learning rate."""

    weight_decay: float = 0.0
    """Adam (L2) weight decay."""

    loss_weights: tuple[float, ...] | None = None
    """Per-action-component weights of the squared error, ``(A,)``; ``None`` = plain MSE."""

    seed: int = 0
    """Seeds weight init (torch) and the batch sampler (numpy); same seed, same weights."""

    log_every: int = 100
    """Record the mean loss every this many batches (and at the last batch)."""

    num_threads: int | None = None
    """``torch.set_num_threads`` during training (restored after); ``None``: 1
    (``bc.train.DEFAULT_NUM_THREADS``), never the process's count. The weights depend on it."""

    def __post_init__(self) -> None:
        _positive_int("batches", self.batches)
        _positive_int("batch_size", self.batch_size)
        _positive_int("log_every", self.log_every)
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"lr must be a finite number > 0, got lr={self.lr!r}")
        if not (math.isfinite(self.weight_decay) and self.weight_decay >= 0):
            raise ValueError(f"weight_decay must be >= 0, got weight_decay={self.weight_decay!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got seed={self.seed!r}")
        if self.num_threads is not None:
            _positive_int("num_threads", self.num_threads)
        if self.loss_weights is not None:
            w = tuple(float(x) for x in self.loss_weights)
            if not w or any(not math.isfinite(x) or x < 0 for x in w) or sum(w) <= 0:
                raise ValueError(
                    f"loss_weights must be finite, >= 0 and not all 0, got {self.loss_weights!r}"
                )
            object.__setattr__(self, "loss_weights", w)


@dataclass(frozen=True)
class BCConfig:
    """The three records together, as stored in a checkpoint's ``config.json``."""

    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able nested dict (tuples become lists)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BCConfig:
        """Inverse of ``to_dict``; unknown keys raise ``ValueError``."""
        return cls(
            preprocess=_build(PreprocessConfig, data.get("preprocess", {})),
            network=_build(NetworkConfig, data.get("network", {})),
            train=_build(TrainConfig, data.get("train", {})),
        )


def _build(cls: type, data: dict[str, Any]) -> Any:
    if not isinstance(data, dict):
        raise ValueError(f"{cls.__name__}: expected a dict, got {type(data).__name__}")
    names = {f.name for f in fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown fields {sorted(unknown)}")
    kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
    return cls(**kwargs)
