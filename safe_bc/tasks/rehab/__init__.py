"""The rehabilitation pathway: a simulated cardiac rehabilitation programme with vector
observations and three monitored safety quantities.

Its parts, all in this folder: the env (:class:`.env.RehabPathwayEnv`, costs in ``info``
itself), the guideline expert (:class:`.expert.GuidelineExpert`), the observed costs
(:func:`.env.observed_costs`, the measured values of the env's true costs) and
:data:`SPEC`, its registry entry. It has no frame drawing (``safe-bc render`` refuses it)
and no action perturbation (``PerturbationConfig(mode="none")``).
"""

from __future__ import annotations

from safe_bc.handover import HandoverConfig
from safe_bc.tasks.carracing.perturb import PerturbationConfig
from safe_bc.tasks.env_config import EnvConfig
from safe_bc.tasks.registry import GymEnv, TaskSpec
from safe_bc.tasks.rehab.env import DEFAULT_N_SESSIONS, REHAB_SAFETY_DIMS, observed_costs
from safe_bc.tasks.rehab.expert import GuidelineConfig, GuidelineExpert

REHAB_ID = "safe_bc/RehabPathway-v0"
"""The task's env id."""

SPEC = TaskSpec(
    name="rehab",
    env=EnvConfig(REHAB_ID),
    gym_envs=(GymEnv(REHAB_ID, "safe_bc.tasks.rehab.env:RehabPathwayEnv", DEFAULT_N_SESSIONS),),
    expert=GuidelineConfig(),
    build_expert=GuidelineExpert,
    perturbation=PerturbationConfig(mode="none"),
    encoding="vector",
    episodes=150,
    eps=0.05,
    # results/validation_size/validation_size.md: the fewest held-out patients whose
    # validation loss spreads by at most 10% (its passes add under 10% to training)
    validation_episodes=64,
    demos="data/rehab_demos",
    results="results/rehab",
    action_bounds=((-1.0, -1.0), (1.0, 1.0)),
    safety_dims=REHAB_SAFETY_DIMS,
    # env.py's costs: peak HR as a fraction of HRR, the model's fatigue (1.0 at its limit),
    # peak systolic BP in 100 mmHg
    safety_units=("HRR fraction", "model units", "100 mmHg"),
    observed_costs=observed_costs,
    # results/rehab/handover_safest/choice.md (stage 3 of tune_jobs/handover/): per-dimension
    # widths, the lightest session in the zone; no candidate of any stage reached zero
    # crossings, the rule's fallback chose the fewest (1 of 3000), then the fewest deferred
    handover=HandoverConfig(
        0.2,
        widths=(("heart_rate", 0.1), ("fatigue", 0.1), ("blood_pressure", 0.2)),
        fallback="safest",
    ),
    # results/improve/rehab/sweep/margin_sweep.md: the sweep's rule chose 0.05
    cost_margin=0.05,
    # env.py's dynamics: heart rate, blood pressure and fatigue rise with the session's
    # intensity and duration (tests/tasks/rehab/test_safer_actions.py)
    safer_actions=(-1, -1),
    # results/selfimprove/rehab/choice.md: the loop's pushes, 2 rounds, kept rows in T_eps
    selfimprove=(
        ("rounds", 2),
        ("pushes", ("0+0.05", "0-0.05", "1+0.05", "1-0.05")),
        ("kept_in", "critical"),
    ),
    episode_name="patient",
)
"""The rehabilitation entry of :data:`safe_bc.tasks.TASKS`."""
