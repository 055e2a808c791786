"""Environments: the CarRacing testbed with safety costs and the rehabilitation pathway."""

from safe_bc.envs.factory import ENV_IDS, EnvConfig, make_env, register_envs
from safe_bc.envs.safety import SAFETY_DIMS, costs_from_distances, pixel_distances
from safe_bc.envs.wrappers import CarRacingSafety, DomainRandomizationError

__all__ = [
    "ENV_IDS",
    "SAFETY_DIMS",
    "CarRacingSafety",
    "DomainRandomizationError",
    "EnvConfig",
    "costs_from_distances",
    "make_env",
    "pixel_distances",
    "register_envs",
]
