"""A third task added through the public API only (``register_task``): a toy lane-keeping env
with a vector observation, two safety costs and a scripted expert, defined here. It is
collected, trained on and evaluated in-process, and (slow) run through a 2-trial study on the
shared local Ray, whose workers register it by importing this module (``SAFE_BC_TASKS``)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from safe_bc.rollout.collect import CollectConfig
from safe_bc.tasks import (
    PLUGINS_VAR,
    TASKS,
    GymEnv,
    PerturbationConfig,
    TaskSpec,
    register_task,
)
from safe_bc.tasks.env_config import EnvConfig

TOY_ID = "safe_bc_tests/ToyLane-v0"
TOY_STEPS = 40


class ToyLane(gym.Env):
    """A point on a lane ``[-1, 1]`` pushed by a random drift; the action ``(1,)`` in
    ``[-1, 1]`` moves it. Observation ``(x, drift)``; safety: distance to each edge."""

    safety_dims = ("left", "right")

    def __init__(self) -> None:
        self.observation_space = spaces.Box(-2.0, 2.0, (2,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def _obs(self) -> np.ndarray:
        return np.array([self.x, self.drift], np.float32)

    def _info(self) -> dict:
        safety = np.array([self.x + 1.0, 1.0 - self.x], np.float32)
        return {
            "safety": safety,
            "cost": (2.0 - safety).astype(np.float32),
            "warmup": False,
            "offroad": bool(abs(self.x) >= 1.0),
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-0.3, 0.3))
        self.drift = float(self.np_random.uniform(-0.05, 0.05))
        return self._obs(), self._info()

    def step(self, action):
        a = float(np.clip(np.asarray(action, np.float32)[0], -1.0, 1.0))
        self.drift = float(np.clip(self.drift + self.np_random.normal(0.0, 0.02), -0.05, 0.05))
        self.x = float(np.clip(self.x + 0.2 * a + self.drift, -1.2, 1.2))
        terminated = abs(self.x) >= 1.0
        return self._obs(), 1.0 - abs(self.x), terminated, False, self._info()


def toy_costs(obs: np.ndarray) -> np.ndarray:
    """The costs as measured from observations: ``(B, 2) -> (B, 2)``."""
    x = np.asarray(obs, np.float64)[:, 0]
    return np.stack([1.0 - x, 1.0 + x], axis=1)


@dataclass(frozen=True)
class ToyExpertConfig:
    """The scripted expert's gain."""

    gain: float = 3.0
    """Action per unit of distance from the centre (the drift is cancelled on top)."""


class ToyExpert:
    """Steer back to the centre against the drift."""

    def __init__(self, config: ToyExpertConfig) -> None:
        self.config = config

    def reset(self, env: gym.Env, rng: np.random.Generator) -> None:
        pass

    def act(self, obs: np.ndarray, env: gym.Env) -> np.ndarray:
        a = -self.config.gain * float(obs[0]) - 5.0 * float(obs[1])
        return np.array([np.clip(a, -1.0, 1.0)], np.float32)


TOY = register_task(
    TaskSpec(
        name="toy",
        env=EnvConfig(TOY_ID),
        gym_envs=(GymEnv(TOY_ID, ToyLane, max_episode_steps=TOY_STEPS),),
        expert=ToyExpertConfig(),
        build_expert=ToyExpert,
        perturbation=PerturbationConfig(mode="none"),
        encoding="vector",
        episodes=6,
        eps=0.1,
        demos="data/toy_demos",
        results="results/toy",
        action_bounds=((-1.0,), (1.0,)),
        safety_dims=ToyLane.safety_dims,
        observed_costs=toy_costs,
    )
)

# Ray workers (started after collection) import this module to register the toy task.
if __name__ not in os.environ.get(PLUGINS_VAR, "").split(","):
    os.environ[PLUGINS_VAR] = ",".join(filter(None, [os.environ.get(PLUGINS_VAR), __name__]))


def _collect_in_process(root: Path, episodes: int = 6) -> Path:
    from safe_bc.data.store import init_dataset, write_episode
    from safe_bc.distributed.collect import dataset_meta
    from safe_bc.rollout.collect import EpisodeMaker

    cfg = CollectConfig.for_task(TOY, episodes=episodes, workers=1)
    meta = init_dataset(root, dataset_meta(cfg))
    maker = EpisodeMaker(cfg)
    try:
        for i in range(cfg.episodes):
            write_episode(root, maker.make(i), meta)
    finally:
        maker.close()
    return root


def test_toy_task_is_registered_through_the_public_api():
    from safe_bc.rollout.collect import build_expert, expert_config_from_dict
    from safe_bc.tasks import task_defaults, task_of
    from safe_bc.tasks.factory import make_env

    assert TASKS["toy"] is TOY and task_of(TOY_ID) == "toy"
    assert task_defaults("toy") is TOY
    assert tuple(TASKS)[:2] == ("carracing", "rehab")
    assert register_task(TOY) is TOY  # the same spec again: nothing changes
    with pytest.raises(ValueError, match="registered already"):
        register_task(TaskSpec(**{**TOY.__dict__, "eps": 0.2}))
    with pytest.raises(ValueError, match="belongs to task 'toy'"):
        register_task(TaskSpec(**{**TOY.__dict__, "name": "toy2"}))
    assert expert_config_from_dict({"type": "ToyExpertConfig", "gain": 2.0}).gain == 2.0
    assert isinstance(build_expert(ToyExpertConfig()), ToyExpert)
    env = make_env(TOY.env)
    try:
        assert isinstance(env.unwrapped, ToyLane) and env.spec.max_episode_steps == TOY_STEPS
    finally:
        env.close()


def test_collect_train_evaluate_on_the_toy_task(tmp_path: Path):
    from safe_bc.bc import load_checkpoint, read_checkpoint_meta
    from safe_bc.cli.commands import main
    from safe_bc.data.store import load_demonstrations, read_meta, read_table
    from safe_bc.distributed.evaluate import evaluate
    from safe_bc.rollout.evaluate import EvalConfig, ExpertSource, NetSource

    demos = _collect_in_process(tmp_path / "demos")
    meta = read_meta(demos)
    assert meta.env_id == TOY_ID and meta.safety_dims == ("left", "right")
    assert meta.action_bounds == TOY.action_bounds
    data = load_demonstrations(demos)
    assert data.observations.shape[1:] == (2,) and len(data) > 6 * 10
    np.testing.assert_allclose(data.costs, toy_costs(data.observations), atol=1e-6)
    again = _collect_in_process(tmp_path / "again")  # same seeds, same dataset
    np.testing.assert_array_equal(load_demonstrations(again).actions, data.actions)

    ckpt = tmp_path / "agent"
    argv = ["train", "--demos", str(demos), "--out", str(ckpt), "--bc.train.batches", "40",
            "--bc.network.hidden", "16", "--selection.alpha", "0.5", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    assert read_checkpoint_meta(ckpt)["extra"]["env_id"] == TOY_ID
    model, bc_cfg = load_checkpoint(ckpt)
    _, sel_meta = read_table(ckpt / "selection.parquet")

    cfg = EvalConfig(episodes=3, workers=0, seed=5, env=TOY.env, eps=TOY.eps)
    result = evaluate(
        {
            "agent": NetSource.from_model(model, bc_cfg),
            "expert": ExpertSource(ToyExpertConfig()),
        },
        cfg,
        np.asarray(sel_meta["thresholds"]),
        progress=False,
    )
    episodes = result.episodes
    assert sorted(set(episodes["policy"])) == ["agent", "expert"]
    assert len(episodes) == 6
    expert = episodes[episodes["policy"] == "expert"]
    assert (expert["steps"] == TOY_STEPS).all() and not expert["terminated"].any()  # in lane
    assert (episodes["steps"] >= 1).all() and (episodes["offroad_steps"] >= 0).all()
    for column in ("safety_mean", "safety_left_mean", "safety_right_mean"):
        assert np.isfinite(episodes[column]).all(), column


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_tiny_study_on_the_toy_task(ray_session, tmp_path: Path):
    from safe_bc.bc import BCConfig, NetworkConfig
    from safe_bc.distributed.collect import collect
    from safe_bc.run_config import RunConfig
    from safe_bc.study.run import run_study
    from safe_bc.study.spec import Choice, Float, StudySpec

    demos = tmp_path / "demos"
    report = collect(CollectConfig.for_task(TOY, episodes=6, workers=2), demos, progress=False)
    assert len(report.collected) == 6
    spec = StudySpec(
        name="toy",
        space={
            "selection.alpha": Float(0.0, 1.0),
            "bc.network.hidden": Choice((8, 16)),
        },
        base=RunConfig(bc=BCConfig(network=NetworkConfig(hidden=16))),
        env=TOY.env,
        demos=demos,
        collect=CollectConfig.for_task(TOY, episodes=6, workers=2),
        critical_eps=TOY.eps,
        trials=2,
        max_concurrent=2,
        cpus_per_trial=0.5,
        batches=30,
        eval_episodes=2,
        screen_episodes=1,
        final_episodes=1,
        final_candidates=1,
        final_train_seeds=1,
        final_workers=0,
        startup_trials=2,
        storage=str(tmp_path / "ray"),
        results=tmp_path / "results",
    )
    outcome = run_study(spec, progress=False)
    assert outcome.complete and outcome.errors == 0
    trials = outcome.trials
    assert len(trials) == 2 and trials["status"].isin(["done", "stopped"]).all()
    assert (trials["status"] == "done").any()


def test_the_tasks_eps_reaches_the_study_the_api_and_the_cli(tmp_path: Path):
    """A plug-in task's eps (0.1 here; CarRacing's 2 px would put every row in T_eps) is the
    width of a study whose base leaves it unset (docs/tasks.md's pattern), of
    ``api.train(TrainJob(...))`` and of ``safe-bc train``: the same T_eps rows on each path."""
    from safe_bc.bc import BCConfig, NetworkConfig, TrainConfig
    from safe_bc.cli import api
    from safe_bc.cli.commands import main
    from safe_bc.cli.jobs import TrainJob
    from safe_bc.data.store import load_demonstrations, read_table
    from safe_bc.methods.experiment import select_for
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import DEFAULT_EPS, SelectionConfig
    from safe_bc.study.spec import StudySpec

    demos = _collect_in_process(tmp_path / "demos")
    bc = BCConfig(network=NetworkConfig(hidden=16), train=TrainConfig(batches=20))
    study = StudySpec("toy", {}, base=RunConfig(bc=bc), env=TOY.env, demos=demos)
    assert study.base.selection.eps == study.critical_eps == TOY.eps
    data = load_demonstrations(demos)
    in_study = select_for(data, study.base.selection).n_critical

    done = api.train(TrainJob(tmp_path / "api", demos, RunConfig(bc=bc), quiet=True))
    _, by_api = done.value
    argv = ["train", "--demos", str(demos), "--out", str(tmp_path / "cli"),
            "--bc.train.batches", "20", "--bc.network.hidden", "16", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    by_cli = read_table(tmp_path / "cli" / "selection.parquet")[0]["critical"].sum()
    assert by_api.config.eps == TOY.eps
    assert in_study == by_api.n_critical == by_cli < by_api.n_valid
    wide = select_for(data, SelectionConfig(eps=DEFAULT_EPS))
    assert wide.n_critical == wide.n_valid != in_study  # what an unresolved 2 px would give
