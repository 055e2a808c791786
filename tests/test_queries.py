"""Critical-zone queries and deferral: asked only in the zone, exact counts, determinism,
resume per round, deferral flags, the stage end to end with a local Ray."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from safe_bc.methods.queries.config import DONE, POLICY, QUERIES, QueryConfig, round_dir
from safe_bc.methods.queries.logic import deferred_steps, query_mask
from safe_bc.methods.queries.rollout import AskingPolicy
from safe_bc.rollout.handover import DeferringPolicy
from safe_bc.selection import CriticalZone

ZONE = CriticalZone((10.0, 5.0), eps=2.0)
COSTS = np.array([[0.0, 0.0], [7.9, 0.0], [8.0, 0.0], [0.0, 3.0], [11.0, 0.0], [9.0, 9.0]])
WARMUP = np.array([False, False, False, False, False, True])
IN_ZONE = [2, 3, 4]  # c_s >= d_s - eps in some dimension, scored


class _Counting:
    """A policy that returns its call count (and counts its calls)."""

    def __init__(self, value: float) -> None:
        self.value, self.calls = value, 0

    def reset(self, env, rng) -> None:
        self.calls = 0

    def act(self, obs, env):
        self.calls += 1
        return np.full(2, self.value, np.float32)


def _drive(policy, costs=COSTS, warmup=WARMUP) -> list[np.ndarray]:
    policy.reset(None, np.random.default_rng(0))
    out = []
    for c, w in zip(costs, warmup, strict=True):
        policy.see({"cost": c, "warmup": w})
        out.append(policy.act(np.zeros(2), None))
    return out


def test_the_expert_is_asked_only_inside_the_zone_and_every_query_is_counted() -> None:
    agent, expert = _Counting(0.0), _Counting(1.0)
    asking = AskingPolicy(agent, expert, ZONE, "critical")
    actions = _drive(asking)
    assert (
        sorted(asking.labels)
        == IN_ZONE
        == np.flatnonzero(query_mask(COSTS, WARMUP, ZONE, "critical")).tolist()
    )
    assert expert.calls == len(IN_ZONE) and agent.calls == len(COSTS)
    assert all((a == 0.0).all() for a in actions)  # the agent's action is executed everywhere
    full = AskingPolicy(_Counting(0.0), expert := _Counting(1.0), ZONE, "full")
    _drive(full)
    assert sorted(full.labels) == [0, 1, 2, 3, 4] and expert.calls == 5  # not in warm-up


def test_deferral_defers_exactly_where_cost_is_within_w_of_the_limit() -> None:
    for width in (0.0, 2.0, 3.0):
        zone = CriticalZone(ZONE.limits, width)
        policy = DeferringPolicy(_Counting(0.0), expert := _Counting(1.0), zone)
        actions = np.stack(_drive(policy))[:, 0]
        want = deferred_steps(COSTS, WARMUP, np.array(ZONE.limits), width)
        limits = np.array(ZONE.limits)
        by_hand = ((limits - width <= COSTS).any(axis=1)) & ~WARMUP
        assert (want == by_hand).all() and (actions == 1.0).tolist() == want.tolist()
        metrics, trace = policy.episode_report()
        assert metrics["deferred_steps"] == want.sum() == expert.calls
        assert metrics["deferred_share"] == pytest.approx(want.sum() / len(COSTS))
        assert trace["deferred"].tolist() == want.tolist()


def test_a_held_handover_keeps_the_expert_for_hold_steps_after_the_zone() -> None:
    """With ``hold`` h the expert acts in the zone and on the h steps after each zone step;
    a new zone step starts the count again; hold 0 is the zone alone."""
    zone = CriticalZone(ZONE.limits, 2.0)
    want = deferred_steps(COSTS, WARMUP, np.array(ZONE.limits), 2.0)
    assert want.any() and not want.all()
    for hold in (0, 1, 3):
        policy = DeferringPolicy(_Counting(0.0), expert := _Counting(1.0), zone, hold=hold)
        actions = np.stack(_drive(policy))[:, 0]
        by_hand = np.array(  # a zone step within the last hold steps, or this one
            [bool(want[i]) or bool(want[max(0, i - hold) : i].any()) for i in range(len(want))]
        )
        assert (actions == 1.0).tolist() == by_hand.tolist() == policy.flags
        assert expert.calls == by_hand.sum() and (by_hand.sum() > want.sum()) == (hold > 0)
    with pytest.raises(ValueError, match="hold"):
        DeferringPolicy(_Counting(0.0), _Counting(1.0), zone, hold=-1)


def test_lookahead_reads_the_cost_extrapolated_from_its_last_change() -> None:
    """With ``lookahead`` k the zone test reads ``c + k (c - c_prev)``: a rising cost hands
    over before the cost itself is in the zone, a falling one later; k = 0 is the zone."""
    limits, width = np.array(ZONE.limits), 2.0
    zone = CriticalZone(ZONE.limits, width)
    for k in (0, 1, 2):
        policy = DeferringPolicy(_Counting(0.0), _Counting(1.0), zone, lookahead=k)
        _drive(policy)
        seen = COSTS + k * np.diff(COSTS, axis=0, prepend=COSTS[:1])
        by_hand = (seen >= limits - width).any(axis=1) & ~WARMUP
        assert policy.flags == by_hand.tolist()
    plain = deferred_steps(COSTS, WARMUP, limits, width).tolist()
    assert policy.flags != plain and by_hand[1] and not plain[1]  # 7.9 rising from 0: early


def test_a_hold_started_only_by_the_named_dimensions() -> None:
    """With ``hold_on`` only a zone step of those dimensions starts the hold; a zone step of
    another dimension defers that step alone (and pauses a running count); ``None`` is any."""
    costs = np.array([[9.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 4.0], [0.0, 0.0], [0.0, 0.0]])
    warmup = np.zeros(len(costs), bool)
    zone = CriticalZone(ZONE.limits, 2.0)  # in the zone: dim 0 at >= 8, dim 1 at >= 3
    flags = {}
    for hold_on in (None, (0,), (1,)):
        policy = DeferringPolicy(_Counting(0.0), _Counting(1.0), zone, hold=2, hold_on=hold_on)
        _drive(policy, costs, warmup)
        flags[hold_on] = [int(f) for f in policy.flags]
    assert flags[None] == [1, 1, 1, 1, 1, 1]
    assert flags[(0,)] == [1, 1, 1, 1, 0, 0]  # dim 1's zone step at 3 holds nothing after it
    assert flags[(1,)] == [1, 0, 0, 1, 1, 1]
    paused = DeferringPolicy(_Counting(0.0), _Counting(1.0), zone, hold=2, hold_on=(0,))
    _drive(paused, np.array([[9.0, 0.0], [0.0, 0.0], [0.0, 4.0], [0.0, 0.0], [0.0, 0.0]]),
           np.zeros(5, bool))  # fmt: skip
    assert paused.flags == [True, True, True, True, False]
    with pytest.raises(ValueError, match="hold_on must be dimension indices"):
        DeferringPolicy(_Counting(0.0), _Counting(1.0), zone, hold=2, hold_on=(2,))


def test_dimension_names_map_to_indices_with_one_line_errors() -> None:
    from safe_bc.rollout.handover import dimension_indices

    assert dimension_indices(("right", "front"), ("left", "front", "right")) == (2, 1)
    assert dimension_indices((), ("left",)) is None
    with pytest.raises(ValueError, match=r"unknown safety dimension\(s\) \['up'\]"):
        dimension_indices(("up",), ("left", "front", "right"))


# --- on the rehab pathway (fast, no Ray) -------------------------------------------------------


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
    return result.model, cfg, demos


def _env_id() -> str:
    from safe_bc.tasks import task_defaults

    return task_defaults("rehab").env.env_id


def _query(rehab_agent, rehab_demos, folder, rollouts=None, **kw):
    from safe_bc.methods.queries.stage import query_run

    model, cfg, _ = rehab_agent
    config = QueryConfig(**{"rounds": 2, "episodes_per_round": 3, "batches": 20, "eps": 0.3, **kw})
    extra = {} if rollouts is None else {"rollouts": rollouts}
    return query_run(config, model, cfg, rehab_demos, _env_id(), folder, **extra)


def _weights(path: Path) -> dict:
    from safe_bc.bc.checkpoint import load_checkpoint

    return load_checkpoint(path)[0].state_dict()


def test_query_counts_match_the_zone_on_the_rollouts_and_runs_are_deterministic(
    rehab_agent, rehab_demos, tmp_path
) -> None:
    from safe_bc.methods.queries.data import load_round

    a = _query(rehab_agent, rehab_demos, tmp_path / "a")
    b = _query(rehab_agent, rehab_demos, tmp_path / "b")
    assert a.total_queries > 0 and a.total_queries == b.total_queries
    for r, summary in enumerate(a.rounds):
        eps_a = load_round(tmp_path / "a" / round_dir(r) / QUERIES)
        eps_b = load_round(tmp_path / "b" / round_dir(r) / QUERIES)
        assert summary["queries"] == sum(int(e.queried.sum()) for e in eps_a)
        for x, y in zip(eps_a, eps_b, strict=True):
            assert np.array_equal(x.observations, y.observations)
            assert np.array_equal(x.actions, y.actions) and np.array_equal(x.steps, y.steps)
            # every queried row is in the zone (the rehab env has no warm-up)
            zone = CriticalZone(tuple(a_lim for a_lim in _limits(rehab_agent)), 0.3)
            assert zone.critical(x.costs[x.queried]).all()
    wa, wb = _weights(a.policy), _weights(b.policy)
    assert all(np.array_equal(wa[k].numpy(), wb[k].numpy()) for k in wa)


def _limits(rehab_agent) -> tuple[float, ...]:
    from safe_bc.methods.experiment import select_for

    _, cfg, demos = rehab_agent
    return tuple(select_for(demos, cfg.selection).thresholds)


def test_queries_in_the_zone_are_every_zone_step_of_the_rollout(rehab_agent, rehab_demos) -> None:
    """The counted queries are exactly the rollout's scored steps in the zone (re-run the
    same episode without asking and count them)."""
    from safe_bc.methods.queries.rollout import QueryJob, query_episode
    from safe_bc.rollout.episode import run_episode
    from safe_bc.rollout.evaluate import NetSource
    from safe_bc.tasks import make_env, task_defaults
    from safe_bc.tasks.rehab.expert import GuidelineExpert

    model, cfg, _ = rehab_agent
    zone = CriticalZone(_limits(rehab_agent), 0.3)
    env = make_env(task_defaults("rehab").env)
    job = QueryJob(
        task_defaults("rehab").env, NetSource.from_model(model, cfg.bc), None, zone, "critical"
    )
    q = query_episode(env, job.agent.build(), GuidelineExpert(), job, 5)
    ep = run_episode(env, job.agent.build(), 5, np.random.default_rng(0), keep_observations=False)
    assert q.n_queries == int(query_mask(ep.costs, ep.warmup, zone, "critical").sum()) > 0
    assert q.length == len(ep) and q.reward == pytest.approx(ep.total_reward)


def test_a_killed_round_reruns_only_what_did_not_finish(rehab_agent, rehab_demos, tmp_path):
    from safe_bc.methods.queries.rollout import query_tracks

    calls: list[int] = []

    def counting(job, seeds):
        calls.append(len(seeds))
        return query_tracks(job, seeds)

    first = _query(rehab_agent, rehab_demos, tmp_path / "run", rollouts=counting)
    assert len(calls) == 2
    before = _weights(first.policy)
    last = tmp_path / "run" / round_dir(1)
    (last / DONE).unlink()  # killed after its queries were written, before it was marked done
    again = _query(rehab_agent, rehab_demos, tmp_path / "run", rollouts=counting)
    assert len(calls) == 2 and again.resumed_rounds == 1  # no new rollout: retraining only
    (last / DONE).unlink()
    (last / QUERIES).unlink()  # killed during its rollouts
    third = _query(rehab_agent, rehab_demos, tmp_path / "run", rollouts=counting)
    assert (len(calls) == 3 and third.rounds == first.rounds) or len(calls) == 3
    after = _weights(third.policy)
    assert all(np.array_equal(before[k].numpy(), after[k].numpy()) for k in before)
    assert (tmp_path / "run" / round_dir(0) / POLICY / "config.json").is_file()
    with pytest.raises(ValueError, match="another query run"):
        _query(rehab_agent, rehab_demos, tmp_path / "run", rounds=3)


def test_full_mode_with_a_budget_keeps_the_first_queries(rehab_agent, rehab_demos, tmp_path):
    run = _query(rehab_agent, rehab_demos, tmp_path / "full", mode="full", query_budget=7)
    assert [r["queries"] for r in run.rounds] == [7, 7]


def test_evaluation_reports_the_deferred_share(rehab_agent, rehab_demos) -> None:
    from safe_bc.rollout.evaluate import NetSource, evaluate_episode
    from safe_bc.rollout.handover import DeferralSource
    from safe_bc.tasks import make_env, task_defaults

    model, cfg, _ = rehab_agent
    limits = np.array(_limits(rehab_agent))
    source = DeferralSource(
        NetSource.from_model(model, cfg.bc), task_defaults("rehab").expert, tuple(limits), 0.3
    )
    env = make_env(task_defaults("rehab").env)
    metrics, trace = evaluate_episode(env, source.build(), 3, thresholds=limits, eps=0.05)
    assert trace["deferred"].sum() == metrics["deferred_steps"] > 0
    assert metrics["deferred_share"] == pytest.approx(trace["deferred"].mean())
    plain, _ = evaluate_episode(env, source.agent.build(), 3, thresholds=limits, eps=0.05)
    assert "deferred_steps" not in plain  # other tables keep their columns


@pytest.mark.parametrize("task", ["rehab", "carracing"])
def test_a_handover_in_lockstep_gives_the_one_env_episodes(
    task, rehab_agent, tiny_demos, tmp_path
) -> None:
    """Envs stepped in lockstep with the agent's forward per row give, per episode, the one-env
    path's rows, flags and counts (held, extrapolated, on real CarRacing and the clinic)."""
    from safe_bc.bc.config import BCConfig, NetworkConfig, TrainConfig
    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods.experiment import train_run
    from safe_bc.rollout.collect import stored_expert_config
    from safe_bc.rollout.evaluate import NetSource, evaluate_episodes
    from safe_bc.rollout.handover import DeferralSource, LockstepDeferringPolicy
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig
    from safe_bc.tasks import make_env, task_defaults

    if task == "rehab":
        model, cfg, demos = rehab_agent
        expert, width, hold_on, max_steps = task_defaults("rehab").expert, 0.3, None, None
    else:
        demos = load_demonstrations(tiny_demos)
        cfg = RunConfig(SelectionConfig(eps=2.0),
                        BCConfig(network=NetworkConfig(channels=(4, 8, 8), hidden=16),
                                 train=TrainConfig(batches=20)))  # fmt: skip
        model = train_run(demos, cfg)[0].model
        expert, width, hold_on, max_steps = stored_expert_config(tiny_demos), 12.0, (1,), 110
    limits = tuple(float(x) for x in demos.limits)
    source = DeferralSource(
        NetSource.from_model(model, cfg.bc), expert, limits, width, "any", 3, 2, hold_on
    )
    assert isinstance(source.build(), LockstepDeferringPolicy)
    seeds = [11, 12, 13]
    kw = {"thresholds": np.asarray(limits), "eps": 2.0, "max_steps": max_steps}
    env_config = task_defaults(task).env
    envs = [make_env(env_config) for _ in seeds]
    alone = evaluate_episodes(envs[:1], source.build(), seeds, **kw)
    together = evaluate_episodes(envs, source.build(), seeds, lockstep_forward="rows", **kw)
    for env in envs:
        env.close()
    assert sum(m["deferred_steps"] for m, _ in alone) > 0  # the handover acted
    for (m1, t1), (m2, t2) in zip(alone, together, strict=True):
        np.testing.assert_equal(m1, m2)  # NaN where a metric does not apply
        assert t1.keys() == t2.keys()
        for key in t1:
            np.testing.assert_array_equal(t1[key], t2[key])


def test_the_stage_runs_end_to_end_with_ray_actors(ray_session, tiny_demos, tmp_path) -> None:
    """CarRacing, 150-step episodes, 10 batches: the registered runner on 2 Ray actors."""
    from safe_bc.bc.config import BCConfig, TrainConfig
    from safe_bc.data.store import load_demonstrations
    from safe_bc.distributed.rollouts import ChunkedRayRollouts
    from safe_bc.methods import METHODS
    from safe_bc.methods.experiment import train_run
    from safe_bc.methods.stages import run_stage
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig

    cfg = RunConfig(SelectionConfig(eps=2.0, alpha=0.5), BCConfig(train=TrainConfig(batches=10)))
    result, _ = train_run(load_demonstrations(tiny_demos), cfg)
    config = QueryConfig(
        rounds=1, episodes_per_round=2, batches=10, max_steps=150, workers=2, eps=40.0
    )
    source, report = run_stage(
        METHODS["queries"], config, result.model, cfg, str(tiny_demos), "CarRacing-v3",
        tmp_path / "stage", parallel=ChunkedRayRollouts,
    )  # fmt: skip
    assert report["queries_total"] > 0
    assert report["queries_per_episode"] == report["queries_total"] / 2
    assert source.build() is not None


def test_the_query_verb_runs_from_a_checkpoint(rehab_start, rehab_demos, tmp_path) -> None:
    from safe_bc.cli.commands import main

    argv = [
        "query",
        "--checkpoint",
        str(rehab_start),
        "--demos",
        str(rehab_demos),
        "--out",
        str(tmp_path / "q"),
        "--rounds",
        "1",
        "--episodes-per-round",
        "2",
        "--workers",
        "0",
    ]
    assert main(argv) == 0
    assert (tmp_path / "q" / round_dir(0) / DONE).is_file()


def test_evaluate_defers_to_the_expert_near_the_limit(rehab_start, tmp_path, capsys) -> None:
    """``safe-bc evaluate --handover.width W``: a width wider than any cost hands every scored
    session to the guideline (the episodes are then the guideline's own on those patients),
    width 0 defers only at or beyond d_s; a negative width is one clear line."""
    import pandas as pd

    from safe_bc.cli.commands import main
    from safe_bc.data.store import read_table
    from safe_bc.distributed.evaluate import evaluate as run_evaluate
    from safe_bc.rollout.evaluate import EvalConfig, ExpertSource
    from safe_bc.tasks import task_defaults

    def run(name: str, *extra: str) -> pd.DataFrame:
        argv = ["evaluate", "--checkpoint", str(rehab_start), "--out", str(tmp_path / name),
                "--episodes", "4", "--workers", "0", "--quiet", *extra]  # fmt: skip
        assert main(argv) == 0
        return pd.read_parquet(tmp_path / name / "episodes.parquet")

    plain = run("plain")
    assert "deferred_share" not in plain
    everywhere = run("all", "--handover.width", "1e9")
    assert (everywhere["deferred_share"] == 1.0).all()
    assert "of steps" in capsys.readouterr().out
    at_limit = run("zero", "--defer-width", "0")  # the flag's former name, an alias
    assert (at_limit["deferred_share"] < 1.0).all()
    assert not everywhere["reward"].equals(plain["reward"])
    guideline = run_evaluate(
        {"expert": ExpertSource(task_defaults("rehab").expert)},
        EvalConfig(episodes=4, workers=0, env=task_defaults("rehab").env),
        np.asarray(read_table(rehab_start / "selection.parquet")[1]["thresholds"]),
    ).episodes
    np.testing.assert_array_equal(guideline["reward"], everywhere["reward"])
    code = main(["evaluate", "--checkpoint", str(rehab_start), "--out", str(tmp_path / "bad"),
                 "--handover.width", "-1", "--quiet"])  # fmt: skip
    assert code != 0
    assert "--handover.width must be a finite number >= 0" in capsys.readouterr().err
    held = run("held", "--handover.width", "0", "--handover.hold", "3", "--handover.lookahead", "2")
    assert "held 3 steps" in (out := capsys.readouterr().out) and "2 steps ahead" in out
    meta = read_table(tmp_path / "held" / "episodes.parquet")[1]
    assert meta["defer_hold"] == 3 and meta["defer_lookahead"] == 2 and len(held) == 4
    code = main(["evaluate", "--checkpoint", str(rehab_start), "--out", str(tmp_path / "bad"),
                 "--handover.hold", "3", "--quiet"])  # fmt: skip
    assert code != 0 and "--handover.hold needs --handover.width" in capsys.readouterr().err
    code = main(["evaluate", "--checkpoint", str(rehab_start), "--out", str(tmp_path / "bad"),
                 "--handover.width", "0", "--handover.hold-on", "x", "--quiet"])  # fmt: skip
    assert code != 0 and "--handover.hold-on needs --handover.hold" in capsys.readouterr().err
    bad = ["--handover.width", "0", "--handover.hold", "2", "--handover.hold-on", "x", "--quiet"]
    code = main(["evaluate", "--checkpoint", str(rehab_start), "--out", str(tmp_path / "b"), *bad])
    assert code != 0 and "unknown safety dimension(s) ['x']" in capsys.readouterr().err
