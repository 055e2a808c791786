"""Behaviour cloning on alpha-mixed batches: configs, preprocessing, net, training, checkpoints.

Only :mod:`~safe_bc.bc.config` (the frozen configs, no torch) is imported with the package;
the torch-side modules (preprocessing, net, policy, training, checkpoints) on first use of one
of their names, so study files and configs can be read without torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from safe_bc.bc.config import BCConfig, NetworkConfig, PreprocessConfig, TrainConfig

if TYPE_CHECKING:
    from safe_bc.bc.checkpoint import (
        CheckpointError,
        CheckpointNotFoundError,
        load_checkpoint,
        read_checkpoint_meta,
        save_checkpoint,
    )
    from safe_bc.bc.net import CAR_RACING_BOUNDS, BCNet, ModelSpec
    from safe_bc.bc.policy import BCPolicy
    from safe_bc.bc.preprocess import (
        frame_stack_index,
        gather_inputs,
        input_shape,
        preprocess_frames,
    )
    from safe_bc.bc.train import BatchBuilder, TrainResult, predict, sampler_for, train_bc

_LAZY = {
    "checkpoint": ("CheckpointError", "CheckpointNotFoundError", "load_checkpoint",
                   "read_checkpoint_meta", "save_checkpoint"),
    "net": ("CAR_RACING_BOUNDS", "BCNet", "ModelSpec"),
    "policy": ("BCPolicy",),
    "preprocess": ("frame_stack_index", "gather_inputs", "input_shape", "preprocess_frames"),
    "train": ("BatchBuilder", "TrainResult", "predict", "sampler_for", "train_bc"),
}  # fmt: skip
"""Module -> the names it defines that ``safe_bc.bc`` hands out on first use (the function
``preprocess`` is not one: ``safe_bc.bc.preprocess`` is its module)."""
_HOME = {name: module for module, names in _LAZY.items() for name in names}


def __getattr__(name: str) -> Any:
    """A name of the torch-side modules, imported on first use (PEP 562)."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from safe_bc.bc import checkpoint, net, policy, preprocess, train

    modules = {"checkpoint": checkpoint, "net": net, "policy": policy,
               "preprocess": preprocess, "train": train}  # fmt: skip
    value = getattr(modules[_HOME[name]], name)
    globals()[name] = value
    return value


__all__ = [
    "CAR_RACING_BOUNDS",
    "BCConfig",
    "BCNet",
    "BCPolicy",
    "BatchBuilder",
    "CheckpointError",
    "CheckpointNotFoundError",
    "ModelSpec",
    "NetworkConfig",
    "PreprocessConfig",
    "TrainConfig",
    "TrainResult",
    "frame_stack_index",
    "gather_inputs",
    "input_shape",
    "load_checkpoint",
    "predict",
    "preprocess_frames",
    "read_checkpoint_meta",
    "sampler_for",
    "save_checkpoint",
    "train_bc",
]
