"""Minari export: a short real dataset survives the round trip through ``minari.load_dataset``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from safe_bc.data.store import DatasetMeta, init_dataset, read_episodes, write_episode
from safe_bc.rollout.collect import CollectConfig, EpisodeMaker, config_dict
from safe_bc.tasks.carracing.perturb import PerturbationConfig
from safe_bc.tasks.env_config import EnvConfig

minari = pytest.importorskip("minari")

from safe_bc.export.minari_export import INFO_KEYS, export_minari  # noqa: E402


def _collect(root: Path, config: CollectConfig, episodes: int) -> Path:
    maker = EpisodeMaker(config)
    try:
        made = [maker.make(i) for i in range(episodes)]
    finally:
        maker.close()
    meta = DatasetMeta(
        env_id=config.env.env_id,
        obs_encoding=config.encoding,
        obs_shape=made[0].observations.shape[1:],
        safety_dims=made[0].safety_dims,
        seed=config.seed,
        max_steps=config.max_steps,
        expert=config_dict(config.expert),
        perturbation=config_dict(config.perturbation),
    )
    meta = init_dataset(root, meta)
    for episode in made:
        write_episode(root, episode, meta)
    return root


@pytest.fixture(scope="module")
def carracing_demos(tmp_path_factory) -> Path:
    """One real 60-step CarRacing episode (the default drift perturbation)."""
    root = tmp_path_factory.mktemp("mx") / "demos"
    return _collect(root, CollectConfig(episodes=1, max_steps=60), 1)


@pytest.fixture(scope="module")
def rehab_demos(tmp_path_factory) -> Path:
    """Two rehab episodes (vector observations, 30 sessions each)."""
    from safe_bc.tasks.rehab.expert import GuidelineConfig

    config = CollectConfig(
        episodes=2,
        env=EnvConfig("safe_bc/RehabPathway-v0"),
        expert=GuidelineConfig(),
        perturbation=PerturbationConfig(mode="none"),
        encoding="vector",
    )
    return _collect(tmp_path_factory.mktemp("mx") / "rehab", config, 2)


def _check_round_trip(demos: Path, dataset_id: str) -> None:
    stored = read_episodes(demos)
    dataset = minari.load_dataset(dataset_id)
    assert dataset.total_episodes == len(stored)
    assert dataset.total_steps == sum(len(e) for e in stored)
    metas = list(dataset.storage.get_episode_metadata(range(len(stored))))
    for ep, got, meta in zip(stored, dataset.iterate_episodes(), metas, strict=True):
        n = len(ep)
        assert meta["seed"] == ep.seed and meta["safe_bc_episode_id"] == ep.episode_id
        assert got.observations.shape == (n + 1, *ep.observations.shape[1:])
        assert got.observations.dtype == ep.observations.dtype
        np.testing.assert_array_equal(got.observations[:n], ep.observations)
        np.testing.assert_array_equal(got.observations[n], ep.observations[-1])
        np.testing.assert_array_equal(got.actions, ep.actions)
        np.testing.assert_array_equal(got.rewards, ep.rewards)
        np.testing.assert_array_equal(got.terminations, ep.terminated)
        np.testing.assert_array_equal(got.truncations, ep.truncated)
        assert set(got.infos) == set(INFO_KEYS)
        assert all(len(v) == n + 1 for v in got.infos.values())
        np.testing.assert_array_equal(got.infos["safety"][:n], ep.safety)
        np.testing.assert_array_equal(got.infos["cost"][:n], ep.costs)
        np.testing.assert_array_equal(got.infos["warmup"][:n], ep.warmup)
        np.testing.assert_array_equal(got.infos["offroad"][:n], ep.offroad)
        np.testing.assert_array_equal(got.infos["executed_action"][:n], ep.executed_actions)
        assert got.infos["repeated_observation"].tolist() == [False] * n + [True]
    assert dataset.storage.metadata["safe_bc_safety_dims"] == list(stored[0].safety_dims)


def test_carracing_round_trip(carracing_demos, tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    dataset = export_minari(carracing_demos, "safe_bc/carracing-drift-v0")
    assert (tmp_path / "minari" / "safe_bc" / "carracing-drift-v0").is_dir()
    assert dataset.observation_space.shape == (96, 96, 3)
    _check_round_trip(carracing_demos, "safe_bc/carracing-drift-v0")
    stored = read_episodes(carracing_demos)[0]
    # the recorded env spec rebuilds the same env, safety wrapper included
    env = dataset.recover_environment()
    try:
        _, info = env.reset(seed=stored.seed)
        assert {"safety", "cost"} <= set(info)
    finally:
        env.close()
    with pytest.raises(ValueError, match="already exists"):
        export_minari(carracing_demos, "safe_bc/carracing-drift-v0")


def test_cli_rehab_round_trip(rehab_demos, tmp_path, monkeypatch, capsys) -> None:
    from safe_bc.cli.commands import main

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    argv = ["export", "--demos", str(rehab_demos), "--format", "minari"]
    argv += ["--dataset-id", "safe_bc/rehab-guideline-v0"]
    code = main(argv)
    assert code == 0, capsys.readouterr().err
    assert "safe_bc/rehab-guideline-v0" in capsys.readouterr().out
    _check_round_trip(rehab_demos, "safe_bc/rehab-guideline-v0")
    code = main(argv)
    assert code == 2 and "already exists" in capsys.readouterr().err


@pytest.mark.parametrize("dataset_id", ["safe_bc/rehab", "../escape-v0", "a b-v0"])
def test_a_bad_dataset_id_is_one_line_before_anything_is_created(
    dataset_id, rehab_demos, tmp_path, monkeypatch, capsys
) -> None:
    from safe_bc.cli.commands import main

    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    argv = ["export", "--demos", str(rehab_demos), "--format", "minari", "--dataset-id"]
    assert main([*argv, dataset_id]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a Minari dataset id" in err[0], err
    assert not root.exists()


def test_rehab_export_carries_the_limits_and_dsrls_scalar_cost(
    rehab_demos, tmp_path, monkeypatch
) -> None:
    """Read back as a DSRL/OSRL loader would: flat transitions with one ``costs`` value each
    (the cost of the state the action led to) and the limits from the dataset metadata; the
    scalar marks the critical zone unless told to mark only steps beyond d_s."""
    from safe_bc.tasks import task_defaults

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    export_minari(rehab_demos, "safe_bc/rehab-limits-v0", eps=0.25)
    dataset = minari.load_dataset("safe_bc/rehab-limits-v0")
    meta = dataset.storage.metadata
    dims = meta["safe_bc_safety_dims"]
    limits = np.array([meta["safe_bc_cost_limits"][d] for d in dims])
    assert meta["safe_bc_eps"] == 0.25 and meta["safe_bc_critical_zone"]["combine"] == "any"
    assert meta["safe_bc_cost_rule"] == "critical"
    stored = read_episodes(rehab_demos)
    scored = np.concatenate([e.costs[~e.warmup] for e in stored])
    np.testing.assert_allclose(limits, scored.max(axis=0), rtol=1e-6)  # d_s: the worst cost
    costs, cost, warmup = _flat(dataset, ("costs", "cost", "warmup"))
    assert len(costs) == dataset.total_steps
    zone = (limits - 0.25).astype(np.float32)
    expected = (np.any(cost >= zone, axis=1) & ~warmup).astype(np.float32)
    np.testing.assert_array_equal(costs, expected)
    assert costs.sum() > 0  # at least the step that set d_s
    marked = sum(np.asarray(ep.infos["costs"])[:-1].sum() for ep in dataset.iterate_episodes())
    assert meta["safe_bc_cost_steps"] == int(marked)  # the stored steps
    # beyond d_s: the expert set defines d_s, so none of its scored steps is; some is at it
    export_minari(rehab_demos, "safe_bc/rehab-beyond-v0", eps=0.25, cost="beyond")
    beyond = minari.load_dataset("safe_bc/rehab-beyond-v0")
    (scalar,) = _flat(beyond, ("costs",))
    assert scalar.sum() == 0 and np.any(np.isclose(cost, limits).any(axis=1))
    assert beyond.storage.metadata["safe_bc_cost_rule"] == "beyond"
    export_minari(rehab_demos, "safe_bc/rehab-default-eps-v0")
    default = minari.load_dataset("safe_bc/rehab-default-eps-v0").storage.metadata
    assert default["safe_bc_eps"] == task_defaults("rehab").eps


def _flat(dataset, keys: tuple[str, ...]) -> list[np.ndarray]:
    """Each info of ``keys`` over all episodes, DSRL's way: one entry per transition, the next
    state's."""
    return [
        np.concatenate([np.asarray(ep.infos[k])[1:] for ep in dataset.iterate_episodes()])
        for k in keys
    ]


def test_osrls_dataset_dict_from_an_export_has_cost_steps(
    rehab_demos, tmp_path, monkeypatch, capsys
) -> None:
    """The dict OSRL's learners read (DSRL's ``get_dataset()``: observations, actions,
    rewards, costs, terminals, timeouts, next_observations), built from ``safe-bc export``'s
    dataset with the default scalar, has aligned rows and steps with cost 1."""
    from safe_bc.cli.commands import main
    from safe_bc.export.minari_export import DSRL_KEYS, dsrl_dataset

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    argv = ["export", "--demos", str(rehab_demos), "--dataset-id", "safe_bc/rehab-osrl-v0"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    data = dsrl_dataset(minari.load_dataset("safe_bc/rehab-osrl-v0"))
    assert tuple(data) == DSRL_KEYS
    stored = read_episodes(rehab_demos)
    n = sum(len(e) for e in stored)
    assert {k: len(v) for k, v in data.items()} == dict.fromkeys(DSRL_KEYS, n)
    assert data["observations"].shape == data["next_observations"].shape == (n, 12)
    np.testing.assert_array_equal(
        data["observations"], np.concatenate([e.observations for e in stored])
    )
    ends = data["terminals"] | data["timeouts"]
    assert ends.sum() == len(stored) and ends[-1]  # each episode ends once, at its last row
    inside = ~ends[:-1]  # within an episode the next observation is the next row's
    np.testing.assert_array_equal(
        data["next_observations"][:-1][inside], data["observations"][1:][inside]
    )
    assert set(np.unique(data["costs"])) <= {0.0, 1.0}
    assert data["costs"].sum() > 0, "no cost step: OSRL's cost-aware learners get no signal"
    assert "scalar costs (critical, eps 0.05)" in out and "step(s) marked" in out


def test_a_plugin_task_with_a_callable_entry_point_is_stored_by_its_import_path(
    tmp_path, monkeypatch
) -> None:
    """``GymEnv(id, Class)`` (docs/tasks.md's form): Minari stores the env spec as JSON, so the
    export stores ``module:Class`` and the dataset rebuilds the env from it."""
    import gymnasium as gym

    from tests.test_task_plugin import TOY_ID, ToyLane, _collect_in_process

    assert gym.spec(TOY_ID).entry_point is ToyLane  # a callable, as registered
    demos = _collect_in_process(tmp_path / "demos", episodes=2)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    dataset = export_minari(demos, "safe_bc/toy-lane-v0")
    assert dataset.env_spec.entry_point == f"{ToyLane.__module__}:ToyLane"
    env = dataset.recover_environment()
    try:
        assert isinstance(env.unwrapped, ToyLane)
    finally:
        env.close()


def test_a_callable_without_an_import_path_is_refused_in_one_line(
    tmp_path, monkeypatch, capsys
) -> None:
    import dataclasses

    import gymnasium as gym

    from safe_bc.cli.commands import main
    from tests.test_task_plugin import TOY_ID, ToyLane, _collect_in_process

    demos = _collect_in_process(tmp_path / "demos", episodes=1)
    spec = dataclasses.replace(gym.registry[TOY_ID], entry_point=lambda **kw: ToyLane())
    monkeypatch.setitem(gym.registry, TOY_ID, spec)
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    argv = ["export", "--demos", str(demos), "--dataset-id", "safe_bc/toy-lambda-v0"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "without an import path" in err[0], err
    assert f"GymEnv({TOY_ID!r}, 'module:Class')" in err[0]
    assert not (root / "safe_bc" / "toy-lambda-v0").exists()
