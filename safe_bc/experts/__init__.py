"""Scripted, privileged experts that produce the demonstrations, and their perturbations."""

from safe_bc.experts.carracing import CarRacingExpert, ExpertConfig
from safe_bc.experts.geometry import ROAD_HALF_WIDTH, lateral_offset, lateral_offsets
from safe_bc.experts.perturb import Perturbation, PerturbationConfig, PerturbationMode

__all__ = [
    "ROAD_HALF_WIDTH",
    "CarRacingExpert",
    "ExpertConfig",
    "Perturbation",
    "PerturbationConfig",
    "PerturbationMode",
    "lateral_offset",
    "lateral_offsets",
]
