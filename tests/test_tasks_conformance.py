"""Every registered task meets the task contract: its env (built by ``make_env``) keeps the
``info`` contract with the spec's safety dimensions, its expert acts inside the action box,
its observed costs have one finite column per dimension, its defaults make a valid
collection, and its defaults (eps, handover), words and metrics reach the study, training and
evaluation paths. Plug-ins are held to the same contract: the toy task of
``tests/test_task_plugin.py`` (``register_task`` in a module) and docs/tasks.md's lane task,
registered as its entry point registers it."""

from __future__ import annotations

import dataclasses
import math
import sys
import types

import gymnasium as gym
import numpy as np
import pytest

import tests.test_task_plugin  # noqa: F401  (registers the toy task)
from safe_bc.rollout.collect import (
    CollectConfig,
    build_expert,
    config_dict,
    expert_config_from_dict,
)
from safe_bc.tasks import TASKS, TaskSpec, register_task, task_defaults, task_of
from safe_bc.tasks.factory import make_env
from safe_bc.tasks.info import INFO_KEYS, InfoContract, StepInfo, check_info

STEPS = 6
DOC_TASK = "lane"
"""The task of docs/tasks.md's complete example."""
NAMES = list(dict.fromkeys([*TASKS, DOC_TASK]))
"""Every registered task and the docs' plug-in."""


def spec_named(task: str) -> TaskSpec:
    """The task's spec; docs/tasks.md's lane task is registered first where no test has yet
    (``tests/test_docs_tasks.py`` loads it through its installed entry point): its module as
    the page writes it, its ``SPEC`` handed to ``register_task``, as the entry point
    ``lane = "lane_task:SPEC"`` does."""
    if task == DOC_TASK and task not in TASKS:
        from tests.test_docs_tasks import doc_files

        if "lane_task" not in sys.modules:
            module = sys.modules["lane_task"] = types.ModuleType("lane_task")
            code = compile(doc_files()["lane_task.py"], "docs/tasks.md (lane_task.py)", "exec")
            exec(code, module.__dict__)
        register_task(sys.modules["lane_task"].SPEC)
    return task_defaults(task)


@pytest.mark.parametrize("task", NAMES)
def test_task_meets_the_contract(task):
    spec = spec_named(task)
    assert spec.name == task and task_of(spec.env.env_id) == task
    assert all(g.id in gym.registry for g in spec.gym_envs)
    cfg = CollectConfig.for_task(spec, episodes=1)  # the defaults are a valid collection
    assert cfg.env == spec.env and cfg.expert == spec.expert
    assert expert_config_from_dict(config_dict(spec.expert)) == spec.expert

    env = make_env(dataclasses.replace(spec.env, max_episode_steps=STEPS + 5))
    expert = build_expert(spec.expert)
    try:
        assert tuple(env.get_wrapper_attr("safety_dims")) == spec.safety_dims
        box = env.action_space
        assert (tuple(map(float, box.low)), tuple(map(float, box.high))) == spec.action_bounds
        rank = len(env.observation_space.shape)
        assert (rank == 1) == (spec.encoding == "vector")
        obs, info = env.reset(seed=7)
        expert.reset(env, np.random.default_rng(7))
        observations, costs = [obs], [check_info(info, spec.safety_dims).cost]
        for _ in range(STEPS):
            action = np.asarray(expert.act(obs, env), np.float32)
            assert action.shape == box.shape and box.contains(action), action
            obs, reward, terminated, truncated, info = env.step(action)
            step = check_info(info, spec.safety_dims)
            assert isinstance(step, StepInfo) and np.isfinite(float(reward))
            assert env.observation_space.contains(obs)
            observations.append(obs)
            costs.append(step.cost)
            if terminated or truncated:
                break
        observed = np.asarray(spec.observed_costs(np.stack(observations)))
        assert observed.shape == (len(observations), len(spec.safety_dims))
        assert np.all(np.isfinite(observed))
        assert np.all(np.isfinite(np.stack(costs)))
    finally:
        env.close()


@pytest.mark.parametrize("task", NAMES)
def test_the_tasks_defaults_reach_a_study_a_training_run_and_a_comparison(task):
    """Where a study, a training run or a comparison leaves the critical-zone width and the
    handover unset, they are the task's (``TaskSpec.eps``, ``TaskSpec.handover``)."""
    from safe_bc.compare.rows import Agent
    from safe_bc.compare.spec import Comparison
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig
    from safe_bc.study.spec import StudySpec
    from safe_bc.tasks import with_task_eps

    spec = spec_named(task)
    study = StudySpec("t", {}, env=spec.env, base=RunConfig())
    assert study.base.selection.eps == study.critical_eps == spec.eps
    assert study.handover == spec.handover and study.task() is spec
    assert StudySpec("t", {}, env=spec.env, handover=None).handover is None
    assert with_task_eps(RunConfig(), spec.env.env_id).selection.eps == spec.eps
    told = RunConfig(SelectionConfig(eps=0.25))
    assert with_task_eps(told, spec.env.env_id) is told
    (row,) = Comparison("t", methods=(Agent("a", SelectionConfig()),), task=task).methods
    assert row.selection.eps == spec.eps


@pytest.mark.parametrize("task", NAMES)
def test_the_tasks_words_and_metrics(task):
    """An episode of the task is scored with the general metrics and the task's own
    (``TaskSpec.metrics``) only: another task's (CarRacing's steering follow-through) are NaN,
    so no table or console shows them; its episodes have a name of their own."""
    from safe_bc.metrics import REGISTRY
    from safe_bc.rollout.episode import run_episode
    from safe_bc.rollout.evaluate import score_episode

    spec = spec_named(task)
    assert spec.episode_name.strip() and spec.episodes_name == f"{spec.episode_name}s"
    assert set(spec.metrics) <= {k for k, m in REGISTRY.items() if not m.general}
    env = make_env(dataclasses.replace(spec.env, max_episode_steps=STEPS))
    try:
        expert = build_expert(spec.expert)
        episode = run_episode(env, expert, 3, np.random.default_rng(3), keep_observations=False)
        metrics, _ = score_episode(env, episode, thresholds=None, eps=spec.eps)
    finally:
        env.close()
    for name, metric in REGISTRY.items():
        if not metric.general and name not in spec.metrics:
            assert math.isnan(metrics[name]), name
    if task != "carracing":
        assert spec.episodes_name != "tracks" and not spec.metrics


GOOD = {"safety": np.ones(2), "cost": np.zeros(2), "warmup": False, "offroad": np.bool_(True)}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"cost": None}, r"lacks \['cost'\]"),
        ({"safety": np.ones(3)}, r"info\['safety'\] must be \(2,\) floats"),
        ({"cost": np.zeros(2, np.int64)}, r"info\['cost'\] must be \(2,\) floats"),
        ({"safety": np.array([1.0, np.nan])}, r"info\['safety'\] must be finite"),
        ({"warmup": 0}, r"info\['warmup'\] must be a bool"),
    ],
)
def test_check_info_names_the_broken_key(change, message):
    info = {**GOOD, **change}
    info = {k: v for k, v in info.items() if v is not None}
    with pytest.raises(ValueError, match=message):
        check_info(info, ("a", "b"))


def test_check_info_gives_the_record():
    step = check_info(GOOD, ("a", "b"))
    assert step.offroad is True and step.warmup is False and step.safety.shape == (2,)
    assert set(INFO_KEYS) == {f.name for f in dataclasses.fields(StepInfo)}


class _Broken(gym.Env):
    """Meets the contract at reset, breaks it on the first step."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    safety_dims = ("a",)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {**GOOD, "safety": np.ones(1), "cost": np.zeros(1)}

    def step(self, action):
        return np.zeros(1, np.float32), 0.0, False, False, {"safety": np.ones(1)}


def test_the_wrapper_checks_each_episodes_first_step():
    env = InfoContract(_Broken())
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"info lacks \['cost', 'warmup', 'offroad'\]"):
        env.step(np.zeros(1, np.float32))
    env.step(np.zeros(1, np.float32))  # later steps are not checked again
    env.reset(seed=1)
    with pytest.raises(ValueError, match="info lacks"):
        env.step(np.zeros(1, np.float32))


class _NoDims(gym.Env):
    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)


def test_an_env_without_safety_dims_is_refused():
    with pytest.raises(ValueError, match="publishes no safety_dims"):
        InfoContract(_NoDims())
