"""The task registry and the action bounds a dataset records."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from safe_bc.bc import CAR_RACING_BOUNDS
from safe_bc.data.store import META_FILE, DatasetMeta, init_dataset, read_meta
from safe_bc.distributed.collect import dataset_meta
from safe_bc.rollout.collect import CollectConfig, env_facts
from safe_bc.tasks import TASKS, action_bounds, dataset_action_bounds, task_defaults, task_of


@pytest.mark.parametrize("task", TASKS)
def test_registry_matches_the_env(task):
    entry = task_defaults(task)
    assert task_of(entry.env.env_id) == task
    assert entry.action_bounds == action_bounds(entry.env)
    _, dims, bounds = env_facts(CollectConfig.for_task(entry, episodes=1))
    assert entry.safety_dims == dims
    assert entry.action_bounds == bounds


def test_carracing_entry_is_the_nets_default():
    assert task_defaults("carracing").action_bounds == CAR_RACING_BOUNDS
    assert task_defaults("carracing").paper_table1
    assert not task_defaults("rehab").paper_table1


def test_unknown_env_id_is_an_error():
    with pytest.raises(ValueError, match="no task uses env 'Pong-v5'"):
        task_of("Pong-v5")


@pytest.mark.parametrize("task", TASKS)
def test_collection_records_the_bounds(tmp_path: Path, task):
    meta = dataset_meta(CollectConfig.for_task(task_defaults(task), episodes=1))
    assert meta.action_bounds == task_defaults(task).action_bounds
    init_dataset(tmp_path, meta)
    assert read_meta(tmp_path) == meta
    assert read_meta(tmp_path).action_bounds == meta.action_bounds
    assert dataset_action_bounds(tmp_path) == task_defaults(task).action_bounds


def _old_dataset(root: Path, meta: DatasetMeta) -> None:
    """``dataset.json`` as written before the bounds were recorded."""
    raw = json.loads(meta.to_json())
    del raw["action_bounds"]
    root.mkdir(parents=True, exist_ok=True)
    (root / META_FILE).write_text(json.dumps(raw, indent=2, sort_keys=True))


@pytest.mark.parametrize("task", TASKS)
def test_old_dataset_falls_back_to_the_registry(tmp_path: Path, task):
    meta = dataset_meta(CollectConfig.for_task(task_defaults(task), episodes=1))
    _old_dataset(tmp_path, meta)
    assert read_meta(tmp_path).action_bounds is None
    assert dataset_action_bounds(tmp_path) == task_defaults(task).action_bounds
    # resuming an old dataset with a new collection: same identity, old metadata kept
    assert init_dataset(tmp_path, meta).action_bounds is None


def test_bounds_are_not_part_of_the_identity():
    meta = dataset_meta(CollectConfig.for_task(task_defaults("rehab"), episodes=1))
    other = dataclasses.replace(meta, action_bounds=None)
    assert meta.identity() == other.identity()
    assert "action_bounds" not in meta.identity()


def test_registry_entries_are_complete():
    assert tuple(TASKS)[:2] == ("carracing", "rehab")  # the built-ins, in order
    for task in TASKS:
        entry = task_defaults(task)
        # None: cannot be rendered / no handover measured / no safer direction of the actions
        optional = {"drawing", "handover", "safer_actions"}
        missing = [
            f.name
            for f in dataclasses.fields(entry)
            if getattr(entry, f.name) is None and f.name not in optional
        ]
        assert not missing, f"{task}: {missing}"
        assert entry.eps > 0
    assert TASKS["carracing"].drawing is not None and TASKS["rehab"].drawing is None


@pytest.mark.parametrize("task", TASKS)
def test_observed_costs_have_the_envs_shape(task):
    """Each entry's cost-from-observation mapping gives one cost per safety dimension, and for
    CarRacing (costs defined on the frame) exactly the env's costs."""
    from safe_bc.tasks import make_env

    entry = task_defaults(task)
    env = make_env(dataclasses.replace(entry.env, max_episode_steps=60))
    try:
        obs, _ = env.reset(seed=5)
        for _ in range(5):
            obs, _, _, _, info = env.step(env.action_space.sample() * 0.0)
        costs = entry.observed_costs(obs[None])
        assert costs.shape == (1, len(entry.safety_dims))
        if task == "carracing":
            assert costs[0] == pytest.approx(info["cost"])
    finally:
        env.close()


def test_env_ids_are_registered_with_their_env_modules():
    import gymnasium as gym

    from safe_bc.tasks import register_envs
    from safe_bc.tasks.rehab import REHAB_ID
    from safe_bc.tasks.rehab.env import DEFAULT_N_SESSIONS, RehabPathwayEnv

    register_envs()
    assert gym.spec(REHAB_ID).max_episode_steps == DEFAULT_N_SESSIONS
    assert isinstance(gym.make(REHAB_ID).unwrapped, RehabPathwayEnv)
