"""The CarRacing testbed: gymnasium's CarRacing-v3 with frame-based safety costs.

Everything CarRacing-specific lives in this folder:

* the env: ``CarRacing-v3`` drawn by one of three renderers (:mod:`.fast_render`, the
  pixel-identical one, with its compiled polygon kernels :mod:`.gfx_kernels`;
  :mod:`.raster_render`, approximate and opt-in, with its compiled vertex transforms
  :mod:`.raster_kernels`; or gymnasium's own), wrapped in
  :class:`.wrapper.CarRacingSafety` (costs, warm-up, off-road in ``info``);
* the costs: :mod:`.costs` (pure: frame -> pixel distances to the grass -> costs; its
  :func:`~.costs.frame_costs` are also the observed costs; :mod:`.ray_kernel`, its rays
  compiled); :mod:`.compiled`, the one switch of the compiled kernels;
* the expert: :mod:`.expert` (pure pursuit on the centre line), :mod:`.geometry` (lateral
  offsets from the track), :mod:`.perturb` (drift / DART perturbations of the executed
  action);
* the pictures: :mod:`.draw` (the safety rays drawn over a frame, the track map);
* :data:`SPEC`, its registry entry.
"""

from __future__ import annotations

import gymnasium as gym

from safe_bc.handover import HandoverConfig
from safe_bc.selection import DEFAULT_EPS
from safe_bc.tasks.carracing.costs import SAFETY_DIMS, frame_costs
from safe_bc.tasks.carracing.draw import DRAWING
from safe_bc.tasks.carracing.expert import CarRacingExpert, ExpertConfig
from safe_bc.tasks.carracing.perturb import PerturbationConfig
from safe_bc.tasks.carracing.wrapper import CarRacingSafety
from safe_bc.tasks.env_config import EnvConfig, Renderer
from safe_bc.tasks.registry import GymEnv, TaskSpec

CARRACING_ID = "CarRacing-v3"
"""The task's env id (gymnasium's own CarRacing; the renderer picks what is built)."""
FAST_CARRACING_ID = "safe_bc/CarRacingFast-v3"
RASTER_CARRACING_ID = "safe_bc/CarRacingRaster-v3"
CARRACING_IDS: dict[Renderer, str] = {
    "exact": FAST_CARRACING_ID,
    "raster": RASTER_CARRACING_ID,
    "stock": CARRACING_ID,
}
"""The gymnasium id that each renderer's CarRacing is made from."""


def make_carracing(config: EnvConfig) -> gym.Env:
    """CarRacing drawn by ``config.renderer``, continuous, fixed colours, costs in ``info``."""
    kwargs = {}
    if config.max_episode_steps is not None:
        kwargs["max_episode_steps"] = config.max_episode_steps
    env = gym.make(
        CARRACING_IDS[config.renderer], continuous=True, domain_randomize=False, **kwargs
    )
    return CarRacingSafety(env)


SPEC = TaskSpec(
    name="carracing",
    env=EnvConfig(CARRACING_ID),
    gym_envs=(
        GymEnv(FAST_CARRACING_ID, "safe_bc.tasks.carracing.fast_render:FastCarRacing", 1000, 900),
        GymEnv(
            RASTER_CARRACING_ID, "safe_bc.tasks.carracing.raster_render:RasterCarRacing", 1000, 900
        ),
    ),
    expert=ExpertConfig(),
    build_expert=CarRacingExpert,
    perturbation=PerturbationConfig(),
    encoding="png",
    episodes=5,
    eps=DEFAULT_EPS,
    demos="data/demos",
    results="results",
    action_bounds=((-1.0, 0.0, 0.0), (1.0, 1.0, 1.0)),  # steer, gas, brake
    safety_dims=SAFETY_DIMS,
    safety_units=("px",) * len(SAFETY_DIMS),  # the rays' pixels to the grass
    observed_costs=frame_costs,
    make_env=make_carracing,
    perturbable=True,
    has_renderer=True,
    paper_table1=True,
    drawing=DRAWING,
    # results/selfimprove/carracing/defer_corner_selection.md: the choice on 3 x 150 selection
    # tracks by the rule fixed before the run (zero crossings, fewest steps deferred), then
    # 0 of 300 fresh episodes beyond d_s on two blocks (defer_corner*.md)
    handover=HandoverConfig(2.0, lookahead=6, hold=6, hold_on=("front",)),
    # results/validation_size/validation_size.md: the most held-out tracks whose validation
    # passes add at most 10% to training (none reaches a 10% spread within that cost)
    validation_episodes=1,
    # the margin the CarRacing improvement ran with (results/improve/carracing), not swept
    cost_margin=1.0,
    # results/selfimprove/carracing/rounds_choice.md and choice.md (SelfImproveConfig's doc)
    selfimprove=(
        ("rounds", 4),
        ("pushes", ("1+0.015", "1+0.025", "2*0.95", "2*0.9", "2*0.75")),
        ("kept_in", "rest"),
    ),
    episode_name="track",
    metrics=("tiles_visited", "steer_autocorr", "steer_change"),
)
"""The CarRacing entry of :data:`safe_bc.tasks.TASKS`."""
