"""Filtered self-imitation: kept data never go beyond d_s - margin (property), pushes back off
in the zone, determinism, resume per round, the keep rule's discard, the stage end to end on
Ray actors and the ``safe-bc improve --method selfimitation`` verb (rehab: fast)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from safe_bc.data.curves import read_events
from safe_bc.data.store import read_table
from safe_bc.methods.rounds import ROUND_CURVE
from safe_bc.methods.selfimprove.config import (
    CURVE,
    DONE,
    KEPT,
    POLICY,
    SelfImproveConfig,
    round_dir,
)
from safe_bc.methods.selfimprove.logic import kept_steps, push_action, window_sums

# --- the keep filter (pure) ----------------------------------------------------------------


@st.composite
def _episodes(draw):
    t = draw(st.integers(1, 40))
    s = draw(st.integers(1, 3))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    # costs straddle the bound often: limits in [1, 3], costs in [0, 4]
    costs = rng.uniform(0, 4, (t, s)).round(1)
    limits = rng.uniform(1, 3, s).round(1)
    final = rng.uniform(0, 4, s).round(1) if draw(st.booleans()) else None
    scored = rng.random(t) < 0.85
    rewards = rng.normal(0, 1, t)
    reference = rng.normal(-0.2, 1, draw(st.integers(1, 45)))
    margin = draw(st.sampled_from([0.0, 0.3, 1.0]))
    unit = draw(st.sampled_from(["episode", "segment"]))
    length = draw(st.integers(1, 12))
    return costs, scored, final, rewards, reference, limits, margin, unit, length


@settings(max_examples=300, deadline=None)
@given(_episodes())
def test_kept_steps_never_start_or_end_beyond_the_limit_minus_the_margin(case) -> None:
    costs, scored, final, rewards, reference, limits, margin, unit, length = case
    keep = kept_steps(unit, costs, scored, final, rewards, reference, limits, margin, length)
    bound = limits - margin
    for t in np.flatnonzero(keep):
        if scored[t]:  # the state a kept step acted in
            assert np.all(costs[t] <= bound), (t, costs[t], bound)
        if t + 1 < len(costs) and scored[t + 1]:  # the state it led to
            assert np.all(costs[t + 1] <= bound)
        if t + 1 == len(costs) and final is not None and scored[t]:  # the last outcome
            assert np.all(final <= bound)
    n = len(rewards)
    if unit == "episode":
        assert keep.all() or not keep.any()
        if keep.any():
            assert rewards.sum() > reference.sum()
    else:  # every kept window beats the reference over the same steps
        mine, ref = window_sums(rewards, length, n), window_sums(reference, length, n)
        for w in range(len(mine)):
            chunk = keep[w * length : (w + 1) * length]
            assert chunk.all() or not chunk.any()
            if chunk.any():
                assert mine[w] > ref[w]


def test_a_safe_better_episode_is_kept_and_one_step_past_the_margin_drops_it() -> None:
    """Not vacuous: the filter keeps what it may (the property above holds for keep-all)."""
    costs, scored = np.full((6, 1), 1.0), np.ones(6, bool)
    args = (np.ones(6), np.zeros(6), np.array([2.0]), 0.5)
    assert kept_steps("episode", costs, scored, np.array([1.0]), *args).all()
    assert not kept_steps("episode", costs, scored, np.array([1.6]), *args).any()  # outcome
    costs[3] = 1.6
    assert not kept_steps("episode", costs, scored, None, *args).any()
    seg = kept_steps("segment", costs, scored, None, *args, segment_steps=2)
    assert seg.tolist() == [True, True, False, False, True, True]  # 2 and 3 touch step 3
    assert kept_steps("segment", costs, ~np.eye(6, dtype=bool)[3], None, *args, 2).all()


def test_pushes_back_off_in_the_zone_and_record_the_agents_own_action() -> None:
    """On rehab: where the state is in the back-off zone the agent's action is executed,
    elsewhere the pushed one; the recorded action is always the agent's."""
    from safe_bc.methods.selfimprove.rollout import Push, ZoneWatch
    from safe_bc.rollout.episode import run_episode
    from safe_bc.tasks import make_env, task_defaults

    class _Fixed:
        def reset(self, env, rng) -> None:
            pass

        def act(self, obs, env):
            return np.array([0.5, 0.2], np.float32)

    env = make_env(task_defaults("rehab").env)
    low, high = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    probe = run_episode(env, _Fixed(), 3, np.random.default_rng(0))
    limits, eps = np.median(probe.costs, axis=0), 0.0  # the zone cuts through the episode
    push = Push("0+0.3", low, high)
    ep = run_episode(
        env, ZoneWatch(_Fixed(), push, limits, eps), 3, np.random.default_rng(0), perturbation=push
    )
    zone = np.any(ep.costs >= limits - eps, axis=1)
    assert zone.any() and (~zone).any()
    assert np.allclose(ep.actions, [0.5, 0.2])
    assert np.allclose(ep.executed_actions[zone], [0.5, 0.2])
    assert np.allclose(ep.executed_actions[~zone], [0.8, 0.2])
    assert push_action(np.array([0.9, 0.0]), [(0, "+", 0.3)], low, high).tolist() == [1.0, 0.0]
    env.close()


def test_the_config_checks_its_fields() -> None:
    with pytest.raises(ValueError, match="push term"):
        SelfImproveConfig(pushes=("1~0.3",))
    with pytest.raises(ValueError, match="keep_unit"):
        SelfImproveConfig(keep_unit="step")  # type: ignore[arg-type]
    assert SelfImproveConfig(workers=3).identity() == SelfImproveConfig().identity()


# --- on the rehab pathway ------------------------------------------------------------------


@pytest.fixture(scope="module")
def rehab_agent(rehab_demos):
    from safe_bc.bc.config import BCConfig, NetworkConfig, TrainConfig
    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods.experiment import train_run
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig
    from safe_bc.tasks import dataset_action_bounds

    cfg = RunConfig(
        SelectionConfig(eps=0.05, alpha=0.5),
        BCConfig(network=NetworkConfig(hidden=16), train=TrainConfig(batches=30)),
    )
    demos = load_demonstrations(rehab_demos)
    result, _ = train_run(demos, cfg, action_bounds=dataset_action_bounds(rehab_demos))
    return result.model, cfg


TINY = {
    "rounds": 2,
    "tracks_per_round": 3,
    "pushes": ("0+0.15", "1+0.15", "0-0.15"),
    "validation_episodes": 4,
    "batches": 20,
    "beyond_limit": 1.0,
}


def _run(rehab_agent, rehab_demos, folder, rollouts=None, train=None, shared=None, **kw):
    from safe_bc.methods.selfimprove.stage import selfimprove_run
    from safe_bc.tasks import task_defaults

    model, cfg = rehab_agent
    config = SelfImproveConfig(**{**TINY, **kw})
    extra: dict = {} if rollouts is None else {"rollouts": rollouts}
    if shared is not None:
        extra["shared"] = shared
    if train is not None:
        extra["train"] = train
    env_id = task_defaults("rehab").env.env_id
    return selfimprove_run(config, model, cfg, rehab_demos, env_id, folder, **extra)


def _weights(path: Path) -> dict:
    from safe_bc.bc.checkpoint import load_checkpoint

    return {k: v.numpy() for k, v in load_checkpoint(path)[0].state_dict().items()}


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_two_runs_keep_the_same_data_and_train_the_same_weights(
    rehab_agent, rehab_demos, tmp_path
) -> None:
    from safe_bc.methods.selfimprove.data import load_round

    a = _run(rehab_agent, rehab_demos, tmp_path / "a")
    b = _run(rehab_agent, rehab_demos, tmp_path / "b")
    assert _no_seconds(a.rounds, b.rounds)
    for r in range(2):
        ta = load_round(tmp_path / "a" / round_dir(r) / KEPT)
        tb = load_round(tmp_path / "b" / round_dir(r) / KEPT)
        assert [t.push_kept for t in ta] == [t.push_kept for t in tb]
        pa = [p for t in ta for p in t.pieces]
        pb = [p for t in tb for p in t.pieces]
        assert len(pa) == len(pb)
        for x, y in zip(pa, pb, strict=True):
            for name in ("steps", "trained", "observations", "actions", "costs"):
                assert np.array_equal(getattr(x, name), getattr(y, name))
        wa, wb = (
            _weights(tmp_path / "a" / round_dir(r) / POLICY),
            _weights(tmp_path / "b" / round_dir(r) / POLICY),
        )
        assert _same(wa, wb)
        # each round's retraining wrote its learning curve (a study's TensorBoard run shows it)
        curve, _ = read_table(tmp_path / "a" / round_dir(r) / ROUND_CURVE)
        assert curve["batch"].is_monotonic_increasing and np.isfinite(curve["train_loss"]).all()
    assert a.kept_steps > 0  # the runs compared kept something


def test_a_run_records_its_demonstrations_relative_to_the_checkout(
    rehab_agent, rehab_demos, tmp_path, monkeypatch
) -> None:
    """Given the demonstrations by an absolute path inside the checkout (a study resolves
    ``data/demos``), the run's identity and its checkpoints name them relative to it: a
    committed run folder names no path of the machine that made it."""
    import functools

    import safe_bc.methods.rounds as rounds
    import safe_bc.methods.selfimprove.run as run
    from safe_bc.data.provenance import repo_relative

    checkout = rehab_demos.parent  # stands in for the repository holding data/
    for module in (run, rounds):
        monkeypatch.setattr(
            module, "repo_relative", functools.partial(repo_relative, root=checkout)
        )
    _run(rehab_agent, rehab_demos, tmp_path / "a", rounds=1)
    want = rehab_demos.relative_to(checkout).as_posix()
    assert json.loads((tmp_path / "a" / "identity.json").read_text())["demos"] == want
    for unit in ("start", f"{round_dir(0)}/{POLICY}"):
        config = json.loads((tmp_path / "a" / unit / "config.json").read_text())
        assert config["extra"]["demos"] == want, unit


def _no_seconds(x: list[dict], y: list[dict]) -> bool:
    drop = ("seconds", "rollout_seconds")
    return [{k: v for k, v in r.items() if k not in drop} for r in x] == [
        {k: v for k, v in r.items() if k not in drop} for r in y
    ]


def test_a_killed_round_reruns_only_what_did_not_finish(rehab_agent, rehab_demos, tmp_path):
    from safe_bc.methods.selfimprove.rollout import ExploreJob, local_rollouts

    explored: list[int] = []

    def counting(job, seeds):
        if isinstance(job, ExploreJob):
            explored.append(len(seeds))
        return local_rollouts(job, seeds)

    first = _run(rehab_agent, rehab_demos, tmp_path / "run", rollouts=counting)
    assert len(explored) == 2 and first.resumed_rounds == 0
    before = _weights(tmp_path / "run" / round_dir(1) / POLICY)
    last = tmp_path / "run" / round_dir(1)
    (last / DONE).unlink()  # killed after its kept data were written, before it was done
    again = _run(rehab_agent, rehab_demos, tmp_path / "run", rollouts=counting)
    assert len(explored) == 2 and again.resumed_rounds == 1  # no new rollout: retraining only
    (last / DONE).unlink()
    (last / KEPT).unlink()  # killed during its rollouts
    third = _run(rehab_agent, rehab_demos, tmp_path / "run", rollouts=counting)
    assert len(explored) == 3 and third.resumed_rounds == 1
    assert _same(before, _weights(last / POLICY))
    assert _no_seconds(first.rounds, third.rounds) and third.agent == first.agent
    # the run's curve, rewritten after each round: the start and both rounds, once each
    curve, _ = read_table(tmp_path / "run" / CURVE)
    assert curve["iteration"].tolist() == [0, 1, 2]
    assert curve.drop(columns="seconds").equals(
        pd.DataFrame(first.history()).drop(columns="seconds")
    )
    events = read_events(tmp_path / "run")
    assert events[events["tag"] == "selfimprove/val_reward"]["step"].tolist() == [0, 1, 2]
    with pytest.raises(ValueError, match="another self-imitation run"):
        _run(rehab_agent, rehab_demos, tmp_path / "run", rounds=3)


def test_alpha_sets_the_retrainings_mix_and_leaves_older_identities_alone(
    rehab_agent, rehab_demos, tmp_path
) -> None:
    """``alpha`` replaces the start's alpha in every retraining (the start's ``T_eps``
    stays); left at ``None`` the identity is the one runs had before the field existed."""
    from safe_bc.methods.rounds import train_local

    seen: list[float] = []

    def recording(job):
        seen.append(job.run_config.selection.alpha)
        return train_local(job)

    assert "alpha" not in SelfImproveConfig().identity()
    assert SelfImproveConfig(alpha=0.9).identity()["alpha"] == 0.9
    with pytest.raises(ValueError, match="alpha"):
        SelfImproveConfig(alpha=1.5)
    _run(rehab_agent, rehab_demos, tmp_path / "mix", train=recording, alpha=0.9, rounds=1)
    _run(rehab_agent, rehab_demos, tmp_path / "start", train=recording, rounds=1)
    assert seen == [0.9, rehab_agent[1].selection.alpha]


def test_a_round_failing_the_keep_rule_is_discarded(rehab_agent, rehab_demos, tmp_path):
    """With a bound no 4 validation episodes can pass, no round is accepted: the run ends
    with the start's weights."""
    run = _run(rehab_agent, rehab_demos, tmp_path / "strict", beyond_limit=0.05)
    assert run.accepted_rounds == 0 and run.agent == "start"
    assert all(r["validation_beyond_upper"] >= 0.05 and r["agent"] == "start" for r in run.rounds)
    model, _ = rehab_agent
    start = {k: v.numpy() for k, v in model.state_dict().items()}
    assert _same(start, _weights(run.policy))


def test_the_stage_runs_end_to_end_with_ray_actors(ray_session, rehab_agent, rehab_demos, tmp_path):
    """The registered runner on 2 Ray actors gives the in-process run's agent."""
    from safe_bc.distributed.rollouts import ChunkedRayRollouts
    from safe_bc.methods import METHODS
    from safe_bc.methods.stages import run_stage
    from safe_bc.tasks import task_defaults

    model, cfg = rehab_agent
    config = SelfImproveConfig(**{**TINY, "rounds": 1, "workers": 2})
    env_id = task_defaults("rehab").env.env_id
    source, report = run_stage(
        METHODS["selfimprove"], config, model, cfg, str(rehab_demos), env_id, tmp_path / "stage",
        parallel=ChunkedRayRollouts,
    )  # fmt: skip
    assert set(report) == set(METHODS["selfimprove"].metrics)
    assert report["selfimprove_kept_steps"] > 0
    local = _run(rehab_agent, rehab_demos, tmp_path / "local", rounds=1)
    assert _same({k: v.numpy() for k, v in source.state.items()}, _weights(local.policy))


def test_the_improve_verb_runs_selfimitation_from_a_checkpoint(
    rehab_start, rehab_demos, tmp_path
) -> None:
    from safe_bc.cli.commands import main

    argv = ["improve", "--method", "selfimitation", "--start", str(rehab_start), "--out",
            str(tmp_path / "si"), "--selfimitation.rounds", "1", "--selfimitation.tracks-per-round",
            "2", "--selfimitation.validation-episodes", "2", "--selfimitation.batches", "10",
            "--quiet"]  # fmt: skip
    assert main(argv) == 0
    assert (tmp_path / "si" / round_dir(0) / DONE).is_file()


def test_study_keys_set_the_stage_config_and_the_verb_parses_pushes() -> None:
    from safe_bc.cli.commands import parse
    from safe_bc.study.spec import Float, StudySpec

    spec = StudySpec(
        "s", {"selfimprove.margin": Float(0.0, 2.0)}, selfimprove=SelfImproveConfig(rounds=3)
    )
    assert [stage.name for stage in spec.stages()] == ["selfimprove"]
    cfg = spec.stage_config("selfimprove", {"selfimprove.margin": 1.0}, seed=4)
    assert (cfg.margin, cfg.seed, cfg.rounds) == (1.0, 4, 3)
    job = parse(["improve", "--start", "a", "--out", "b", "--method", "selfimitation",
                 "--selfimitation.pushes", "1+0.03", "2*0.9"])[1]  # fmt: skip
    assert job.method == "selfimitation" and job.selfimitation.pushes == ("1+0.03", "2*0.9")
    assert parse(["improve", "--start", "a", "--out", "b"])[1].method == "ppo_lagrangian"


def test_the_stage_runs_on_carracing_with_60_step_episodes(tiny_demos, tmp_path) -> None:
    """CarRacing, 60-step episodes, 1 track, the task's pushes (gas, brake), 10 batches."""
    from safe_bc.bc.config import BCConfig, TrainConfig
    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods import METHODS
    from safe_bc.methods.experiment import train_run
    from safe_bc.methods.selfimprove.config import TASK_DEFAULTS
    from safe_bc.methods.selfimprove.data import load_round
    from safe_bc.methods.stages import run_stage
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig

    cfg = RunConfig(SelectionConfig(eps=2.0, alpha=0.5), BCConfig(train=TrainConfig(batches=10)))
    result, _ = train_run(load_demonstrations(tiny_demos), cfg)
    config = SelfImproveConfig(
        rounds=1, tracks_per_round=1, validation_episodes=1, batches=10, max_steps=60
    )
    folder = tmp_path / "stage"
    source, report = run_stage(
        METHODS["selfimprove"], config, result.model, cfg, str(tiny_demos), "CarRacing-v3", folder
    )
    (track,) = load_round(folder / round_dir(0) / KEPT)
    assert len(track.push_rewards) == len(TASK_DEFAULTS["carracing"]["pushes"])
    assert report["selfimprove_kept_steps"] == sum(track.push_kept)
    assert source.build() is not None


def test_car_frames_read_from_disk_train_the_weights_of_frames_in_memory(
    tiny_demos, tmp_path
) -> None:
    """Two accepted CarRacing rounds (validation rewards made to rise, so both are kept and
    round 1 retrains on round 0's rows too): reading the training frames from the run's
    kept-frame store gives the weights of holding them in memory (no frame file is left); a
    round killed after appending its frames reruns to the same net."""
    from safe_bc.bc.config import BCConfig, TrainConfig
    from safe_bc.data.frames import checksum_path
    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods.experiment import train_run
    from safe_bc.methods.selfimprove.config import FRAMES
    from safe_bc.methods.selfimprove.rollout import ValidateJob, local_rollouts
    from safe_bc.methods.selfimprove.stage import selfimprove_run
    from safe_bc.methods.selfimprove.store import KeptFrameStore
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig

    cfg = RunConfig(SelectionConfig(eps=2.0, alpha=0.5), BCConfig(train=TrainConfig(batches=200)))
    result, _ = train_run(load_demonstrations(tiny_demos), cfg)
    # pushes large enough that some pushed run beats a tiny agent's run on any CPU
    config = SelfImproveConfig(
        rounds=2, tracks_per_round=3, validation_episodes=1, batches=10, max_steps=100,
        margin=0.0, beyond_limit=1.0, pushes=("1+0.3", "1+0.5"),
    )  # fmt: skip

    def run(folder: Path, on_disk: bool, validated: int = 0, explored: list | None = None):
        calls = [1] * validated

        def rising(job, seeds):
            rows = local_rollouts(job, seeds)
            if explored is not None and not isinstance(job, ValidateJob):
                explored.append(job)
            if isinstance(job, ValidateJob):
                calls.append(1)
                rows = [{**m, "reward": 1000.0 * len(calls), "any_violation": 0} for m in rows]
            return rows

        return selfimprove_run(
            config, result.model, cfg, str(tiny_demos), "CarRacing-v3", folder,
            rollouts=rising, frames_on_disk=on_disk,
        )  # fmt: skip

    disk = run(tmp_path / "disk", True)
    memory = run(tmp_path / "memory", False)
    assert disk.accepted_rounds == 2 and disk.rounds[0]["kept_steps"] > 0
    assert _no_seconds(disk.rounds, memory.rounds)
    for r in range(2):
        assert not (tmp_path / "disk" / round_dir(r) / FRAMES).exists()
        assert not checksum_path(tmp_path / "disk" / round_dir(r) / FRAMES).exists()
        assert _same(
            _weights(tmp_path / "disk" / round_dir(r) / POLICY),
            _weights(tmp_path / "memory" / round_dir(r) / POLICY),
        )
    # round 1 trained on round 0's kept rows read back from the run's kept-frame store: a
    # dropped or misordered frame would change its weights (or the row count aggregate_rows
    # checks)
    store = KeptFrameStore(tmp_path / "disk", (96, 96, 3))
    assert [(e["round"], e["accepted"]) for e in store.rounds] == [(0, True), (1, True)]
    rows, before = store.rows, _weights(tmp_path / "disk" / round_dir(1) / POLICY)
    # killed after round 1 appended its frames and wrote its round file, with a torn append
    # after them: the rerun explores nothing, cuts the torn rows and trains the same net
    last = tmp_path / "disk" / round_dir(1)
    (last / DONE).unlink()
    with open(store.path, "ab") as f:
        f.write(b"\x01" * store.row_bytes * 5)
    explored: list = []
    rerun = run(tmp_path / "disk", True, validated=2, explored=explored)
    assert not explored and _no_seconds(rerun.rounds, disk.rounds)
    assert _same(before, _weights(last / POLICY))
    assert KeptFrameStore(tmp_path / "disk", (96, 96, 3)).rows == rows
    assert store.path.stat().st_size == rows * store.row_bytes
    # killed after the append, before its round file: the rows are rolled back, explored again
    (last / DONE).unlink()
    (last / KEPT).unlink()
    rerun = run(tmp_path / "disk", True, validated=2, explored=explored)
    assert len(explored) == 1 and _no_seconds(rerun.rounds, disk.rounds)
    assert _same(before, _weights(last / POLICY))
    assert store.path.stat().st_size == rows * store.row_bytes


# --- keeping only what beats the expert, exploring under the handover ----------------------


def test_new_options_enter_the_identity_only_when_set_and_are_checked() -> None:
    from safe_bc.handover import HandoverConfig

    plain = SelfImproveConfig().identity()
    assert not {"keep_against", "keep_best", "handover"} & set(plain)
    set_ = SelfImproveConfig(
        keep_against="expert", keep_best=2, handover=HandoverConfig(2.0, 6, 6, ("front",))
    ).identity()
    assert set_["keep_against"] == "expert" and set_["keep_best"] == 2
    assert set_["handover"] == {"width": 2.0, "lookahead": 6, "hold": 6, "hold_on": ["front"]}
    with pytest.raises(ValueError, match="keep_against"):
        SelfImproveConfig(keep_against="teacher")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="keep_best"):
        SelfImproveConfig(keep_best=0)
    with pytest.raises(ValueError, match="HandoverConfig"):
        SelfImproveConfig(handover={"width": 2.0})  # type: ignore[arg-type]


def test_under_the_handover_the_expert_acts_unpushed_and_the_agent_is_pushed() -> None:
    """On rehab: where the handover defers, the expert's action is executed and recorded;
    elsewhere the agent's pushed action is executed."""
    from safe_bc.handover import HandoverConfig
    from safe_bc.methods.selfimprove.rollout import ExploreJob, Push
    from safe_bc.rollout.episode import run_episode
    from safe_bc.tasks import make_env, task_defaults

    class _Fixed:
        def __init__(self, action) -> None:
            self.action = np.asarray(action, np.float32)

        def reset(self, env, rng) -> None:
            pass

        def act(self, obs, env):
            return self.action.copy()

    env = make_env(task_defaults("rehab").env)
    low, high = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    agent, expert = _Fixed([0.5, 0.2]), _Fixed([-0.4, -0.3])
    probe = run_episode(env, agent, 3, np.random.default_rng(0))
    limits = tuple(float(x) for x in np.median(probe.costs, axis=0))
    job = ExploreJob(
        None, None, ("0+0.3",), (low, high), limits, handover=HandoverConfig(0.0),
        dims=task_defaults("rehab").safety_dims,
    )  # fmt: skip
    push = Push("0+0.3", low, high)
    driver = job.driver(agent, expert, push)
    ep = run_episode(env, driver, 3, np.random.default_rng(0), perturbation=push)
    deferred = np.asarray(driver.deferring.flags, bool)
    assert deferred.any() and (~deferred).any() and driver.deferred_steps == deferred.sum()
    assert np.allclose(ep.executed_actions[deferred], [-0.4, -0.3])
    assert np.allclose(ep.actions[deferred], [-0.4, -0.3])
    assert np.allclose(ep.executed_actions[~deferred], [0.8, 0.2])
    with pytest.raises(ValueError, match="expert"):
        job.driver(agent, None, push)
    env.close()


def test_a_run_against_the_expert_keeps_only_runs_that_beat_it(
    rehab_agent, rehab_demos, tmp_path
) -> None:
    """The bar is the expert's run on the same track, at most one pushed run per track is
    kept, the runs drive under the task's handover, and the round records all of it."""
    from safe_bc.methods.selfimprove.data import load_round
    from safe_bc.tasks import task_defaults

    handover = task_defaults("rehab").handover
    run = _run(
        rehab_agent, rehab_demos, tmp_path / "x", rounds=1, keep_against="expert", keep_best=1,
        handover=handover, pushes=("0+0.15", "1+0.15", "0-0.15", "1-0.15"), tracks_per_round=6,
    )  # fmt: skip
    (summary,) = run.rounds
    assert np.isfinite(summary["expert_reward_mean"])
    assert 0 <= summary["pushed_deferred_share"] <= 1
    tracks = load_round(tmp_path / "x" / round_dir(0) / KEPT)
    assert all(np.isfinite(t.expert_reward) and t.expert_steps > 0 for t in tracks)
    assert all(len(t.push_deferred) == 4 for t in tracks)
    assert any(t.pieces for t in tracks)  # the rule kept something to check
    for t in tracks:
        assert len(t.pieces) <= 1
        for p in t.pieces:
            assert t.push_rewards[p.push] > t.expert_reward
    env_steps = sum(t.reference_steps + sum(t.push_steps) + t.expert_steps for t in tracks)
    assert summary["env_steps"] == env_steps


def test_a_tasks_record_carries_its_self_imitation_defaults() -> None:
    """A task names its measured self-imitation settings on its record; a config that leaves
    them at None takes them, a task without any is refused naming what to set."""
    from dataclasses import replace

    from safe_bc.methods.selfimprove.config import LOOP_PUSHES
    from safe_bc.tasks import register_task, task_defaults, task_of
    from safe_bc.tasks.registry import TASKS

    rehab = task_defaults("rehab")
    assert dict(rehab.selfimprove)["pushes"] == LOOP_PUSHES["rehab"]
    assert SelfImproveConfig().for_task("rehab").kept_in == "critical"
    twin = replace(
        rehab, name="rehab_twin", env=replace(rehab.env, env_id="rehab_twin-v0"), gym_envs=(),
        selfimprove=(("rounds", 7), ("pushes", ("0+0.1",)), ("kept_in", "zone")),
    )  # fmt: skip
    try:
        register_task(twin)
        resolved = SelfImproveConfig().for_task("rehab_twin")
        assert (resolved.rounds, resolved.pushes, resolved.kept_in) == (7, ("0+0.1",), "zone")
    finally:
        TASKS.pop("rehab_twin", None)
        task_defaults.cache_clear()
        task_of.cache_clear()
    with pytest.raises(ValueError, match="no self-imitation defaults"):
        SelfImproveConfig().for_task("rehab_twin")


# --- lockstep rollouts ----------------------------------------------------------------------


def _same_tracks(a: list, b: list) -> bool:
    """Two lists of TrackResults equal in every field and every kept row, bit for bit."""
    from dataclasses import fields

    for x, y in zip(a, b, strict=True):
        for f in fields(x):
            u, v = getattr(x, f.name), getattr(y, f.name)
            if f.name == "pieces":
                if len(u) != len(v):
                    return False
                for p, q in zip(u, v, strict=True):
                    if (p.seed, p.push) != (q.seed, q.push):
                        return False
                    for name in ("steps", "trained", "observations", "actions", "costs"):
                        if not np.array_equal(getattr(p, name), getattr(q, name)):
                            return False
            elif not np.array_equal(np.asarray(u), np.asarray(v), equal_nan=True):
                return False
    return True


def _explore_job(task: str, source, limits, **kw):
    from safe_bc.methods.selfimprove.rollout import ExploreJob
    from safe_bc.tasks import task_defaults

    spec = task_defaults(task)
    bounds = tuple(np.asarray(b, np.float32) for b in spec.action_bounds)
    return ExploreJob(spec.env, source, limits=limits, action_bounds=bounds, **kw)


@pytest.mark.parametrize("under_handover, bar", [(False, "agent"), (True, "expert")])
def test_lockstep_runs_are_the_one_env_runs_bit_for_bit(
    rehab_agent, rehab_demos, under_handover, bar
) -> None:
    """Rehab: every track's reference, pushed and expert runs, stepped 3 at a time with
    one-row forward passes, give the one-env TrackResults exactly (kept rows included), with
    the expert's bar, the best 2 runs kept and, in one case, the handover."""
    from dataclasses import replace

    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods.experiment import select_for
    from safe_bc.methods.selfimprove.rollout import explore_track
    from safe_bc.rollout.collect import build_expert, stored_expert_config
    from safe_bc.rollout.evaluate import NetSource
    from safe_bc.tasks import make_env, task_defaults

    model, cfg = rehab_agent
    spec = task_defaults("rehab")
    expert_cfg = stored_expert_config(rehab_demos)
    limits = select_for(load_demonstrations(rehab_demos), cfg.selection).thresholds
    job = _explore_job(
        "rehab", NetSource.from_model(model, cfg.bc), tuple(float(x) for x in limits),
        pushes=("0+0.15", "1+0.15", "0-0.15"), keep_against=bar, keep_best=2,
        expert=expert_cfg, handover=spec.handover if under_handover else None,
        dims=spec.safety_dims, backoff_eps=0.05,
    )  # fmt: skip
    seeds = [11, 12, 13, 14, 15, 16]
    env = make_env(spec.env)
    agent = job.agent.build()
    one = [explore_track(env, agent, job, s, build_expert(expert_cfg)) for s in seeds]
    env.close()
    pooled = replace(job, lockstep_envs=3).run(seeds)
    assert _same_tracks(one, pooled)
    assert any(t.pieces for t in one)  # the rule kept rows to compare
    again = replace(job, lockstep_envs=3, forward="batched")
    assert _same_tracks(again.run(seeds), again.run(seeds))


def test_car_lockstep_runs_are_the_one_env_runs_bit_for_bit(tiny_demos) -> None:
    """CarRacing frames, 100-step runs, 3 pushes that release the brake (a 10-batch agent
    brakes), on 2 tracks with 10-step windows kept: 3 envs in lockstep with one-row forward
    passes give the one-env runs' outcomes and kept frames exactly."""
    from dataclasses import replace

    from safe_bc.bc.config import BCConfig, TrainConfig
    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods.experiment import train_run
    from safe_bc.methods.selfimprove.rollout import explore_track
    from safe_bc.rollout.evaluate import NetSource
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig
    from safe_bc.tasks import make_env, task_defaults

    cfg = RunConfig(SelectionConfig(eps=2.0, alpha=0.5), BCConfig(train=TrainConfig(batches=10)))
    result, _ = train_run(load_demonstrations(tiny_demos), cfg)
    job = _explore_job(
        "carracing", NetSource.from_model(result.model, cfg.bc), (1e3, 1e3, 1e3),
        pushes=("2*0", "1+0.5,2*0", "0+0.3,2*0"), max_steps=100, backoff_eps=2.0,
        unit="segment", segment_steps=10,
    )  # fmt: skip
    seeds = [5, 6]
    env = make_env(task_defaults("carracing").env)
    one = [explore_track(env, job.agent.build(), job, s) for s in seeds]
    env.close()
    pooled = replace(job, lockstep_envs=3).run(seeds)
    assert _same_tracks(one, pooled)
    assert sum(len(t.pieces) for t in one) > 0  # frames were kept and compared


# --- the kept-frame store -------------------------------------------------------------------


def _synthetic_round(rng, seeds, frame=(6, 5, 3)):
    """TrackResults with random kept frames (a piece without rows among them)."""
    from safe_bc.methods.selfimprove.rollout import KeptPiece, TrackResult

    tracks = []
    for seed in seeds:
        pieces = []
        for push, rows in enumerate(rng.integers(0, 7, 2) * (seed != 20)):  # 20: no rows
            pieces.append(
                KeptPiece(
                    seed=seed, push=push, steps=np.arange(rows, dtype=np.int64),
                    trained=rng.random(rows) < 0.7,
                    observations=rng.integers(0, 256, (rows, *frame), dtype=np.uint8),
                    actions=rng.random((rows, 3), dtype=np.float32),
                    costs=rng.random((rows, 2), dtype=np.float32),
                )
            )  # fmt: skip
        tracks.append(
            TrackResult(seed, 1.0, 0, (1.0, 2.0), (0, 0), (1, 1), 10, (10, 10), tuple(pieces))
        )
    return tracks


def test_the_kept_frame_store_gives_the_frame_file_each_round_rebuilt(tmp_path) -> None:
    """Demonstrations plus accepted rounds plus this round's rows: read through the store and
    the demonstrations' frames, the same array (and any rows asked) as the frame file the
    retraining rebuilt before from the compressed round files; a rejected round's rows are cut
    off and round files written beside the store hold no frames but read back the same."""
    from safe_bc.data.frames import FrameFile, write_frame_file
    from safe_bc.methods.selfimprove.data import (
        frame_chunks,
        holds_frames,
        load_round,
        round_frames,
        save_round,
    )
    from safe_bc.methods.selfimprove.store import ConcatFrames, KeptFrameStore

    rng = np.random.default_rng(3)
    frame = (6, 5, 3)
    demos = rng.integers(0, 256, (9, *frame), dtype=np.uint8)
    store = KeptFrameStore(tmp_path, frame)
    files, accepted = [], []
    for r, ok in enumerate([True, False, False, True, True]):
        tracks = _synthetic_round(rng, [10 * r, 10 * r + 1] if r != 2 else [20], frame)
        old, new = tmp_path / f"old{r}.npz", tmp_path / f"new{r}.npz"
        save_round(old, tracks)
        store.append(r, round_frames(tracks))
        save_round(new, tracks, frames=False)
        assert holds_frames(old) and not holds_frames(new)
        a, b = load_round(old), load_round(new)
        assert [len(p.steps) for t in a for p in t.pieces] == [p.observations.shape[0] for t in b
                                                               for p in t.pieces]  # fmt: skip
        assert _same_tracks([replace(t, pieces=()) for t in a], [replace(t, pieces=()) for t in b])
        mine = [p for t in tracks for p in t.pieces]
        n = len(demos) + sum(len(p.steps) for f in files for t in load_round(f) for p in t.pieces)
        n += sum(len(p.steps) for p in mine)
        chunks = frame_chunks(demos, files, mine)
        rebuilt = FrameFile(write_frame_file(tmp_path / "f.npy", (n, *frame), chunks), (n, *frame))
        read = ConcatFrames([demos, store.frames()])
        assert read.shape == rebuilt.shape
        assert np.array_equal(np.asarray(read), np.asarray(rebuilt))
        rows = rng.integers(0, n, 50)
        assert np.array_equal(read[rows], rebuilt[rows]) and np.array_equal(read[-1], rebuilt[-1])
        rebuilt.close()
        read.close()
        store.settle(r, ok)
        if ok:
            files.append(old)
            accepted.append((r, sum(len(p.steps) for p in mine)))
    assert [e["round"] for e in store.rounds] == [0, 3, 4]
    assert store.path.stat().st_size == store.rows * store.row_bytes
    assert store.rows == sum(n for _, n in accepted)


def test_an_interrupted_rounds_appended_frames_are_rolled_back_on_resume(tmp_path) -> None:
    """Rows appended by a round killed before it was settled are cut when the run resumes
    (unless they are the rerun round's own, its round file written); accepted rounds stay;
    a run folder from before the store gets its accepted rounds' frames from their files."""
    from safe_bc.methods.selfimprove.data import round_frames, save_round
    from safe_bc.methods.selfimprove.run import _sync_store
    from safe_bc.methods.selfimprove.store import KeptFrameStore

    rng = np.random.default_rng(5)
    frame = (4, 4, 3)
    rounds = [_synthetic_round(rng, [r], frame) for r in range(3)]
    frames = [np.concatenate(list(round_frames(t))) for t in rounds]
    store = KeptFrameStore(tmp_path, frame)
    store.append(0, round_frames(rounds[0]))
    store.settle(0, True)
    store.append(1, round_frames(rounds[1]))  # killed here: appended, never settled
    n0 = len(frames[0])
    save_round(tmp_path / "k0.npz", rounds[0], frames=False)
    kept = [(0, n0, tmp_path / "k0.npz")]
    again = KeptFrameStore(tmp_path, frame)  # the resumed run
    _sync_store(again, kept, 1, tmp_path / "r1.npz")  # no round file of round 1
    assert again.rows == n0 and [e["round"] for e in again.rounds] == [0]
    assert again.path.stat().st_size == n0 * again.row_bytes
    assert np.array_equal(np.asarray(again.frames()), frames[0])
    assert KeptFrameStore(tmp_path, frame).rows == n0  # the index says so too
    # its round file written (frames in the store): the rerun keeps its rows, cuts the rest
    again.append(1, round_frames(rounds[1]))
    with open(again.path, "ab") as f:
        f.write(b"\x07" * again.row_bytes * 2)  # a torn later append
    save_round(tmp_path / "r1.npz", rounds[1], frames=False)
    third = KeptFrameStore(tmp_path, frame)
    _sync_store(third, kept, 1, tmp_path / "r1.npz")
    assert third.pending(1) and (tmp_path / "r1.npz").is_file()
    assert np.array_equal(np.asarray(third.frames()), np.concatenate(frames[:2]))
    # an accepted round's record lost, its rows gone: the rerun's round file is dropped
    third._cut(0)
    with pytest.raises(ValueError, match="lost them"):
        _sync_store(KeptFrameStore(tmp_path, frame), kept, 1, tmp_path / "r1.npz")
    # a folder from before the store: the accepted rounds' files hold their frames
    save_round(tmp_path / "r0.npz", rounds[0])
    old = KeptFrameStore(tmp_path, frame)
    _sync_store(old, [(0, n0, tmp_path / "r0.npz")], 1, tmp_path / "r1.npz")
    assert not (tmp_path / "r1.npz").exists()  # its frames were lost: it explores again
    assert np.array_equal(np.asarray(old.frames()), frames[0])
    assert old.rounds == [{"round": 0, "start": 0, "stop": n0, "accepted": True}]


# --- work shared between the runs of one start ------------------------------------------------


def _counting(jobs: list):
    """``local_rollouts`` recording each job's type and track count."""
    from safe_bc.methods.selfimprove.rollout import local_rollouts

    def rollouts(job, seeds):
        jobs.append((type(job).__name__, len(seeds), job))
        return local_rollouts(job, seeds)

    return rollouts


def _run_files_equal(a: Path, b: Path, rounds: int) -> None:
    """Two run folders hold the same weights each round, the same round records and start
    validation (wall times and ``shared_hits`` aside) and the same curve (its seconds aside)."""
    from safe_bc.methods.rounds import read_json

    drop = ("seconds", "rollout_seconds", "shared_hits")

    def record(path: Path) -> dict:
        return {k: v for k, v in read_json(path).items() if k not in drop}

    assert record(a / "start_validation.json") == record(b / "start_validation.json")
    for r in range(rounds):
        assert record(a / round_dir(r) / DONE) == record(b / round_dir(r) / DONE)
        assert _same(_weights(a / round_dir(r) / POLICY), _weights(b / round_dir(r) / POLICY))
    ca, _ = read_table(a / CURVE)
    cb, _ = read_table(b / CURVE)
    pd.testing.assert_frame_equal(ca.drop(columns="seconds"), cb.drop(columns="seconds"))


def test_runs_of_one_start_share_its_validation_and_the_experts_runs_bit_for_bit(
    rehab_agent, rehab_demos, tmp_path
) -> None:
    """Rehab, candidates B (kept only above the expert's run) and D (B under the handover,
    the best run per track): B with the shared folder cold runs and stores the start's
    validation and the expert's runs, the same run as without one; D then reads them all
    (no validation of the start, no expert run) and is D without one, weights, round records
    and curve; the env steps recorded are what the run needed, the reads are ``shared_hits``."""
    from safe_bc.methods import METHODS, Start
    from safe_bc.methods.selfimprove.shared import SharedResults
    from safe_bc.tasks import task_defaults

    model, cfg = rehab_agent
    shared = tmp_path / "_shared"
    b = {"keep_against": "expert"}
    d = {**b, "handover": task_defaults("rehab").handover, "keep_best": 1}
    plain_b = _run(rehab_agent, rehab_demos, tmp_path / "plain_b", **b)
    plain_d = _run(rehab_agent, rehab_demos, tmp_path / "plain_d", **d)
    cold_jobs: list = []
    cold = _run(rehab_agent, rehab_demos, tmp_path / "b", _counting(cold_jobs), shared=shared, **b)
    tracks = TINY["tracks_per_round"]
    assert cold.start_validation["shared_hits"] == 0
    assert [r["shared_hits"] for r in cold.rounds] == [0, 0]
    assert [j[:2] for j in cold_jobs if j[0] == "ExpertRunsJob"] == [("ExpertRunsJob", tracks)] * 2
    assert len(list(shared.glob("*.json"))) == 1 + 2 * tracks
    _run_files_equal(tmp_path / "plain_b", tmp_path / "b", 2)
    assert cold.env_steps == plain_b.env_steps
    assert cold.validation_env_steps == plain_b.validation_env_steps

    warm_jobs: list = []
    warm = _run(rehab_agent, rehab_demos, tmp_path / "d", _counting(warm_jobs), shared=shared, **d)
    assert warm.start_validation["shared_hits"] == 1
    assert [r["shared_hits"] for r in warm.rounds] == [tracks, tracks]
    assert [j[0] for j in warm_jobs] == ["ExploreJob", "ValidateJob"] * 2  # nothing repeated
    assert all(len(j[2].bars) == tracks for j in warm_jobs if j[0] == "ExploreJob")
    assert plain_b.kept_steps > 0 and plain_d.kept_steps > 0  # the bars decided something
    _run_files_equal(tmp_path / "plain_d", tmp_path / "d", 2)
    assert warm.env_steps == plain_d.env_steps  # the expert's steps counted as before
    assert warm.validation_env_steps == plain_d.validation_env_steps
    assert len(list(shared.glob("*.json"))) == 1 + 2 * tracks

    # a comparison's runner hands its runs folder's shared folder on with the start
    start = Start(model, cfg, str(rehab_demos), task_defaults("rehab").env, shared=shared)
    config = SelfImproveConfig(**{**TINY, **b})
    again = METHODS["selfimprove"].run(config, start, tmp_path / "b2").result
    assert again.start_validation["shared_hits"] == 1
    assert [r["shared_hits"] for r in again.rounds] == [tracks, tracks]
    _run_files_equal(tmp_path / "plain_b", tmp_path / "b2", 2)

    # a record is read only for its own ingredients: another start's or a tampered one is not
    store = SharedResults(shared)
    (path,) = [p for p in shared.glob("*.json") if "validation" in p.read_text()]
    record = json.loads(path.read_text())
    assert store.get(record["ingredients"]) == record["value"]
    other = {**record["ingredients"], "tracks": [1, 2]}
    assert store.get(other) is None
    record["ingredients"]["eps"] = 0.5
    path.write_text(json.dumps(record))
    assert store.get({**record["ingredients"], "eps": cfg.selection.eps}) is None


def test_an_experts_run_is_stored_exactly() -> None:
    from safe_bc.methods.selfimprove.shared import expert_run_from_json, expert_run_to_json

    rng = np.random.default_rng(0)
    for dtype in (np.float32, np.float64):
        rewards = rng.normal(size=50).astype(dtype) / 7
        back = expert_run_from_json(json.loads(json.dumps(expert_run_to_json((rewards, 1.5, 50)))))
        assert back[0].dtype == rewards.dtype and np.array_equal(back[0], rewards)
        assert back[1:] == (1.5, 50)


def test_car_runs_read_the_experts_stored_runs_bit_for_bit() -> None:
    """CarRacing frames, an untrained net, 60-step runs on 2 tracks against the expert's run:
    the expert's runs run apart (:class:`ExpertRunsJob`, each in a fresh env and expert) and
    stored as JSON are the runs the round's job makes in its env after the agent's, reward for
    reward, and give its tracks (an untrained net's pushed runs never beat the expert here, so
    nothing is kept: the rehab run above compares kept rows)."""
    from dataclasses import replace

    import torch

    from safe_bc.bc import BCConfig, BCNet, ModelSpec
    from safe_bc.methods.selfimprove.rollout import _bar
    from safe_bc.methods.selfimprove.shared import expert_run_from_json, expert_run_to_json
    from safe_bc.rollout.episode import run_episode
    from safe_bc.rollout.evaluate import NetSource
    from safe_bc.tasks import make_env, task_defaults
    from safe_bc.tasks.carracing.expert import CarRacingExpert, ExpertConfig

    bc = BCConfig()
    torch.manual_seed(0)
    model = BCNet(ModelSpec.for_data((96, 96, 3), 3), bc.preprocess, bc.network)
    job = _explore_job(
        "carracing", NetSource.from_model(model, bc), (1e3, 1e3, 1e3),
        pushes=("1+1,2*0",), max_steps=60, keep_against="expert", expert=ExpertConfig(),
        lockstep_envs=3,
    )  # fmt: skip
    seeds = [5, 6]
    runs = job.expert_runs().run(seeds)
    stored = [expert_run_from_json(json.loads(json.dumps(expert_run_to_json(r)))) for r in runs]
    env = make_env(task_defaults("carracing").env)
    agent, expert = job.agent.build(), CarRacingExpert(ExpertConfig())
    for s, (rewards, total, steps) in zip(seeds, stored, strict=True):
        ref = run_episode(env, agent, s, job.episode_rng(s, 0), keep_observations=False,
                          max_steps=60)  # fmt: skip
        bar = _bar(env, job, s, ref, expert)  # as the round's job runs it, after the agent
        assert bar[0].dtype == rewards.dtype and np.array_equal(bar[0], rewards)
        assert bar[1:] == (total, steps) == (total, 60)
    env.close()
    inline = job.run(seeds)
    assert _same_tracks(inline, replace(job, bars=dict(zip(seeds, stored, strict=True))).run(seeds))
