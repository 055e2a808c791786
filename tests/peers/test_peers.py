"""``make peers``'s logic in safe_bc's environment: the demonstrations in DSRL's layout, the
plan and budgets, an exported actor as a policy, the table. The peers' own training runs in
``.venv-peers`` (``test_osrl.py``)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import torch

from safe_bc.data.store import completed_episodes, episode_path, read_episode, read_meta
from safe_bc.export.limits import dataset_zone, step_costs
from safe_bc.export.minari_export import DSRL_KEYS
from safe_bc.peers.bridge import META, ScriptedSource
from safe_bc.peers.data import dsrl_from_demos, from_unit, kept_by_budget, to_unit
from safe_bc.peers.plan import ALGORITHMS, budget_lines, peer, training_plan
from safe_bc.peers.table import markdown_table, peers_table, policy_key, split_policies


def test_the_demonstrations_as_dsrls_dict_carry_the_critical_zone_cost(rehab_demos) -> None:
    data, info = dsrl_from_demos(rehab_demos)
    meta = read_meta(rehab_demos)
    episodes = [read_episode(episode_path(rehab_demos, i), meta)
                for i in completed_episodes(rehab_demos, meta)]  # fmt: skip
    n = sum(len(e) for e in episodes)
    assert tuple(data) == DSRL_KEYS and {len(v) for v in data.values()} == {n}
    np.testing.assert_array_equal(
        data["observations"], np.concatenate([e.observations for e in episodes])
    )
    zone = dataset_zone(rehab_demos, meta)
    expected = []
    for e in episodes:  # the next state's scalar; the last transition repeats the last step
        c = step_costs(e.costs, e.warmup, zone)
        expected.append(np.concatenate([c[1:], c[-1:]]))
    np.testing.assert_array_equal(data["costs"], np.concatenate(expected))
    assert info["cost_transitions"] == int(data["costs"].sum())
    assert sum(info["episode_costs"]) == info["cost_transitions"]
    assert (data["terminals"] | data["timeouts"]).sum() == len(episodes)
    assert np.abs(data["actions"]).max() <= 1.0
    assert info["state_dim"] == 12 and info["action_dim"] == 2
    assert info["cost_limits"] == pytest.approx(list(zone.limits))


def test_actions_map_to_the_unit_box_and_back() -> None:
    low, high = np.array([0.0, -2.0]), np.array([1.0, 2.0])
    a = np.array([[0.25, 1.0], [1.0, -2.0]])
    np.testing.assert_allclose(from_unit(to_unit(a, low, high), low, high), a, atol=1e-6)
    assert from_unit(np.array([5.0, -5.0]), low, high).tolist() == [1.0, -2.0]
    assert kept_by_budget([0, 1, 2, 1], 1) == 3


def test_the_plan_names_every_peer_and_its_budget() -> None:
    plan = training_plan(state_dim=12, action_dim=2, episode_len=30, cost_limit=1, seeds=[0, 1])
    assert [p["name"] for p in plan["peers"]] == ["BC-All", "BC-Safe", "COptiDICE", "CPQ"]
    assert all(p["updates"] < p["osrl_updates"] for p in plan["peers"])
    assert json.loads(json.dumps(plan)) == plan  # plain JSON for the peers' env
    assert peer("CPQ").algorithm == "CPQ" and len(ALGORITHMS) == 4
    with pytest.raises(ValueError, match="unknown peer 'CDT'; peers: BC-All"):
        peer("CDT")
    with pytest.raises(ValueError, match="cost budget"):
        training_plan(state_dim=1, action_dim=1, episode_len=1, cost_limit=-1, seeds=[0])
    (line,) = budget_lines(
        {
            "BC-All": {
                "updates": 5000,
                "osrl_updates": 300000,
                "seconds_per_update": 0.006,
                "seeds": 3,
            }
        }
    )
    assert line.startswith("BC-All: 5,000 updates of 300,000") and "0.5 h per seed" in line


def _actor(tmp_path, meta: dict) -> str:
    net = torch.nn.Sequential(torch.nn.Linear(3, 2), torch.nn.Tanh())
    path = tmp_path / "a.pt"
    torch.jit.save(torch.jit.trace(net, torch.zeros(1, 3)), str(path),
                   _extra_files={META: json.dumps(meta)})  # fmt: skip
    return str(path)


def test_an_exported_actor_acts_as_a_policy_in_the_action_bounds(tmp_path) -> None:
    path = _actor(tmp_path, {"action_low": [0.0, -2.0], "action_high": [1.0, 2.0]})
    policy = ScriptedSource.from_file(path).build()
    policy.reset(None, np.random.default_rng(0))
    action = policy.act(np.ones(3, np.float32), None)
    assert action.shape == (2,) and action.dtype == np.float32
    assert 0.0 <= action[0] <= 1.0 and -2.0 <= action[1] <= 2.0
    with pytest.raises(ValueError, match="no action bounds"):
        ScriptedSource.from_file(_actor(tmp_path, {}))


def _episodes() -> pd.DataFrame:
    rows = []
    for t in range(4):
        rows.append({"policy": policy_key("expert", None), "env_seed": t, "reward": 10.0 + t,
                     "safety_mean": 0.3, "any_violation": 0.0})  # fmt: skip
        for s in range(2):
            rows.append({"policy": policy_key("peer", s), "env_seed": t, "reward": 12.0 + t,
                         "safety_mean": 0.1, "any_violation": float(t == 0)})  # fmt: skip
    return split_policies(pd.DataFrame(rows))


def test_the_table_pairs_each_row_with_the_expert_and_counts_beyond() -> None:
    rows = {"expert": {"source": "the task's expert"}, "peer": {"source": "OSRL", "budget": "9"}}
    table = peers_table(_episodes(), "expert", rows).set_index("method")
    assert list(table.index) == ["expert", "peer"]
    assert table.loc["peer", "d_reward"] == pytest.approx(2.0)
    assert table.loc["peer", ["beyond", "n_episodes", "train_seeds", "patients"]].tolist() == [
        2, 8, 2, 4,
    ]  # fmt: skip
    assert np.isnan(table.loc["expert", "d_reward"]) and table.loc["expert", "beyond"] == 0
    lines = markdown_table(table.reset_index(), "expert")
    assert len(lines) == 4 and "| 2 x 4 |" in lines[3] and "+2.00 [+2.00, +2.00]" in lines[3]
    with pytest.raises(ValueError, match="row 'missing' has no episodes"):
        peers_table(_episodes(), "expert", {**rows, "missing": {}})


def test_make_peers_prepares_trains_in_its_own_env_then_evaluates() -> None:
    import shutil
    import subprocess
    from pathlib import Path

    if shutil.which("make") is None:
        pytest.skip("needs make")
    root = Path(__file__).resolve().parents[2]
    dry = subprocess.run(["make", "-n", "-C", str(root), "peers"],
                         capture_output=True, text=True, check=True).stdout  # fmt: skip
    steps = [line for line in dry.splitlines() if "safe_bc.peers" in line or "osrl_train" in line]
    assert [s.split()[-1] if "osrl" in s else s.split()[3] for s in steps] == [
        "prepare", "runs/peers", "evaluate",
    ]  # fmt: skip
    assert ".venv-peers/bin/python peers/osrl_train.py" in steps[1]


def test_the_peers_block_is_new_to_every_clinic_table_and_study() -> None:
    """The committed table's patients (block 95) are no clinic comparison's and no clinic
    study's (a block of another task holds other envs: the car's third design drives tracks of
    block 95)."""
    from pathlib import Path

    from safe_bc.compare.families import load_comparisons
    from safe_bc.peers.run import BLOCK
    from safe_bc.study.spec import load_study
    from safe_bc.tasks import task_of

    root = Path(__file__).resolve().parents[2]
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        tables = {
            c.eval_seed
            for f in sorted((root / "tune_jobs/compare").glob("*.py"))
            for c in load_comparisons(f, planned=True).values()
            if c.task == "rehab"
        }
    studies = [load_study(p) for p in sorted((root / "tune_jobs").glob("*.py"))]
    clinic = [s for s in studies if task_of(s.env.env_id) == "rehab"]
    used = tables | {b for s in clinic for b in (s.eval_seed, s.final_seed, s.certify_seed)}
    assert clinic and tables and BLOCK not in used


def test_a_plugin_vector_task_gives_dsrls_dict_and_frames_are_refused(
    tmp_path, monkeypatch
) -> None:
    """Any task with vector observations: a plug-in task's demonstrations give the dict; a set
    of frames is refused in one line naming why."""
    from dataclasses import replace

    import safe_bc.peers.data as peers_data
    from safe_bc.data.store import DatasetError
    from tests.test_task_plugin import _collect_in_process

    demos = _collect_in_process(tmp_path / "demos", episodes=2)
    data, info = dsrl_from_demos(demos)
    assert info["episodes"] == 2 and len(data["costs"]) == info["transitions"] > 0
    frames = replace(read_meta(demos), obs_encoding="png", obs_shape=(96, 96, 3))
    monkeypatch.setattr(peers_data, "read_dataset_meta", lambda root: frames)
    with pytest.raises(DatasetError, match=r"vector observations .* frozen encoder"):
        dsrl_from_demos(demos)
