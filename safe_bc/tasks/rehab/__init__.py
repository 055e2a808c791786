"""The rehabilitation pathway: a simulated cardiac rehabilitation programme with vector
observations and three monitored safety quantities.

Its parts: the env (:class:`safe_bc.envs.rehab.RehabPathwayEnv`, costs in ``info`` itself),
the expert (:class:`safe_bc.experts.rehab.GuidelineExpert`), the observed costs
(:func:`safe_bc.envs.rehab.observed_costs`, the measured values of the env's true costs) and
:data:`SPEC`, its registry entry.
"""

from __future__ import annotations

from safe_bc.envs.config import EnvConfig
from safe_bc.envs.rehab import DEFAULT_N_SESSIONS, REHAB_SAFETY_DIMS, observed_costs
from safe_bc.experts.perturb import PerturbationConfig
from safe_bc.experts.rehab import GuidelineConfig, GuidelineExpert
from safe_bc.tasks.registry import GymEnv, TaskSpec

REHAB_ID = "safe_bc/RehabPathway-v0"
"""The task's env id."""

SPEC = TaskSpec(
    name="rehab",
    env=EnvConfig(REHAB_ID),
    gym_envs=(GymEnv(REHAB_ID, "safe_bc.envs.rehab:RehabPathwayEnv", DEFAULT_N_SESSIONS),),
    expert=GuidelineConfig(),
    build_expert=GuidelineExpert,
    perturbation=PerturbationConfig(mode="none"),
    encoding="vector",
    episodes=150,
    eps=0.05,
    demos="data/rehab_demos",
    results="results/rehab",
    action_bounds=((-1.0, -1.0), (1.0, 1.0)),
    safety_dims=REHAB_SAFETY_DIMS,
    observed_costs=observed_costs,
)
"""The rehabilitation entry of :data:`safe_bc.tasks.TASKS`."""
