"""Behaviour cloning on alpha-mixed batches: configs, preprocessing, net, training, checkpoints."""

from __future__ import annotations

from safe_bc.bc.checkpoint import (
    CheckpointError,
    CheckpointNotFoundError,
    load_checkpoint,
    read_checkpoint_meta,
    save_checkpoint,
)
from safe_bc.bc.config import BCConfig, NetworkConfig, PreprocessConfig, TrainConfig
from safe_bc.bc.net import CAR_RACING_BOUNDS, BCNet, ModelSpec
from safe_bc.bc.policy import BCPolicy
from safe_bc.bc.preprocess import (
    frame_stack_index,
    gather_inputs,
    input_shape,
    preprocess,
    preprocess_frames,
)
from safe_bc.bc.train import BatchBuilder, TrainResult, predict, sampler_for, train_bc

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
    "preprocess",
    "preprocess_frames",
    "read_checkpoint_meta",
    "sampler_for",
    "save_checkpoint",
    "train_bc",
]
