"""Train OSRL's own algorithms on a safe_bc task's demonstrations (run in ``.venv-peers``).

``make peers`` runs this in the peers' environment (``make peers-env``: osrl-lib 0.1.0 and its
companions installed without their pins, docs/peers.md), which never imports safe_bc. It reads
what ``python -m safe_bc.peers prepare`` wrote to ``RUNS``:

* ``dsrl.npz``: the demonstrations as DSRL's dataset dict (``observations``,
  ``next_observations``, ``actions`` scaled to [-1, 1], ``rewards``, ``costs``, ``terminals``,
  ``timeouts``), the scalar cost the critical-zone indicator of the Minari export;
* ``plan.json``: the peers, OSRL's settings for each, their updates, the cost budget per
  episode, ``episode_len`` and the training seeds;

and writes, per peer and seed, ``RUNS/actors/<peer>_seed<k>.pt``: the deterministic actor as
TorchScript (observation -> action in [-1, 1]; safe_bc maps it back to the action bounds),
with the plan's entry and the measured time in the file's ``safe_bc.json``; then
``RUNS/train.json``, what each peer got (updates, seconds per update, the episodes BC-Safe
kept). An actor trained from the same plan entry and data is kept; one from another (a changed
budget or dataset) is trained again.

Each update draws a batch of transitions uniformly with replacement, as OSRL's loaders do one
transition at a time (here vectorised: the same distribution, far faster). OSRL's trainers are
given ``env=None``: their ``evaluate()`` is never called (it reads a scalar ``info["cost"]``);
safe_bc evaluates the actors instead.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from importlib.metadata import version
from pathlib import Path

import numpy as np
import torch
from torch import nn


def load(runs: Path) -> tuple[dict[str, np.ndarray], dict]:
    with np.load(runs / "dsrl.npz") as f:
        data = {k: f[k] for k in f.files}
    plan = json.loads((runs / "plan.json").read_text())
    return data, plan


class Deterministic(nn.Module):
    """OSRL's actor at test time: BC's MLP (tanh output), or the squashed Gaussian's
    ``tanh(mu)`` (OSRL's ``deterministic=True``)."""

    def __init__(self, actor: nn.Module, squashed: bool) -> None:
        super().__init__()
        self.actor = actor
        self.squashed = squashed

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if self.squashed:
            return torch.tanh(self.actor.mu_layer(self.actor.net(obs)))
        return self.actor(obs)


def batches(data: dict[str, np.ndarray], keys: list[str], size: int, seed: int):
    rng = np.random.default_rng(seed)
    n = len(data["observations"])
    tensors = {k: torch.as_tensor(data[k], dtype=torch.float32) for k in keys}
    while True:
        idx = torch.as_tensor(rng.integers(0, n, size))
        yield [tensors[k][idx] for k in keys]


def with_done(data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``done`` and ``is_init`` as OSRL's TransitionDataset makes them."""
    out = dict(data)
    out["done"] = np.logical_or(data["terminals"], data["timeouts"]).astype(np.float32)
    out["is_init"] = out["done"].copy()
    out["is_init"][1:] = out["done"][:-1]
    out["is_init"][0] = 1.0
    return out


def train_bc(data, plan, p, seed):
    from osrl.algorithms import BC, BCTrainer
    from osrl.common.dataset import process_bc_dataset

    s = p["settings"]
    kept = {k: v.copy() for k, v in data.items()}
    episodes_before = int(np.logical_or(data["terminals"], data["timeouts"]).sum())
    process_bc_dataset(kept, plan["cost_limit"], 1.0, s["bc_mode"])  # OSRL's gamma for BC: 1
    model = BC(plan["state_dim"], plan["action_dim"], 1.0, s["a_hidden_sizes"],
               plan["episode_len"], "cpu")  # fmt: skip
    trainer = BCTrainer(model, None, actor_lr=s["actor_lr"], bc_mode=s["bc_mode"],
                        cost_limit=plan["cost_limit"], device="cpu")  # fmt: skip
    draw = batches(kept, ["observations", "actions"], s["batch_size"], seed)
    for _ in range(p["updates"]):
        obs, act = next(draw)
        trainer.train_one_step(obs, act)
    kept_episodes = int(np.logical_or(kept["terminals"], kept["timeouts"]).sum())
    info = {"transitions": len(kept["observations"]), "episodes": kept_episodes,
            "episodes_of": episodes_before}  # fmt: skip
    return Deterministic(model.actor, squashed=False), info


def train_coptidice(data, plan, p, seed):
    from osrl.algorithms import COptiDICE, COptiDICETrainer

    s = p["settings"]
    d = with_done(data)
    model = COptiDICE(
        plan["state_dim"], plan["action_dim"], 1.0, s["f_type"], float(d["is_init"].mean()),
        d["observations"].std(0, keepdims=True), d["actions"].std(0, keepdims=True),
        s["a_hidden_sizes"], s["c_hidden_sizes"], s["gamma"], s["alpha"], s["cost_ub_epsilon"],
        s["num_nu"], s["num_chi"], plan["cost_limit"], plan["episode_len"], "cpu",
    )  # fmt: skip
    trainer = COptiDICETrainer(model, None, actor_lr=s["actor_lr"], critic_lr=s["critic_lr"],
                               scalar_lr=s["scalar_lr"], reward_scale=s["reward_scale"],
                               cost_scale=s["cost_scale"], device="cpu")  # fmt: skip
    keys = ["observations", "next_observations", "actions", "rewards", "costs", "done", "is_init"]
    draw = batches(d, keys, s["batch_size"], seed)
    for _ in range(p["updates"]):
        obs, nxt, act, rew, cost, done, init = next(draw)
        trainer.train_one_step(
            [obs, nxt, act, rew * s["reward_scale"], cost * s["cost_scale"], done, init]
        )
    return Deterministic(model.actor, squashed=True), {"transitions": len(d["observations"])}


def train_cpq(data, plan, p, seed):
    from osrl.algorithms import CPQ, CPQTrainer

    s = p["settings"]
    d = with_done(data)
    model = CPQ(
        plan["state_dim"], plan["action_dim"], 1.0, s["a_hidden_sizes"], s["c_hidden_sizes"],
        s["vae_hidden_sizes"], s["sample_action_num"], s["gamma"], s["tau"], s["beta"],
        s["num_q"], s["num_qc"], s["qc_scalar"], plan["cost_limit"], plan["episode_len"], "cpu",
    )  # fmt: skip
    trainer = CPQTrainer(model, None, actor_lr=s["actor_lr"], critic_lr=s["critic_lr"],
                         alpha_lr=s["alpha_lr"], vae_lr=s["vae_lr"],
                         reward_scale=s["reward_scale"], cost_scale=s["cost_scale"],
                         device="cpu")  # fmt: skip
    keys = ["observations", "next_observations", "actions", "rewards", "costs", "done"]
    draw = batches(d, keys, s["batch_size"], seed)
    for _ in range(p["updates"]):
        obs, nxt, act, rew, cost, done = next(draw)
        trainer.train_one_step(obs, nxt, act, rew * s["reward_scale"],
                               cost * s["cost_scale"], done)  # fmt: skip
    return Deterministic(model.actor, squashed=True), {"transitions": len(d["observations"])}


TRAIN = {"BC": train_bc, "COptiDICE": train_coptidice, "CPQ": train_cpq}


def plan_key(plan: dict, p: dict) -> str:
    """What an actor was trained from: the peer's entry, the budget, the data's digest."""
    made = {k: plan.get(k) for k in ("cost_limit", "episode_len", "action_low", "action_high")}
    made["digest"] = (plan.get("dataset") or {}).get("digest")
    return json.dumps({**made, "peer": p}, sort_keys=True)


def actor_path(runs: Path, name: str, seed: int) -> Path:
    return runs / "actors" / f"{name}_seed{seed}.pt"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=Path, required=True, help="folder of dsrl.npz, plan.json")
    parser.add_argument("--only", nargs="*", default=None, help="peers to train (default: all)")
    args = parser.parse_args(argv)
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    warnings.filterwarnings("ignore", r"`torch\.jit\.\w+` is deprecated", DeprecationWarning)
    data, plan = load(args.runs)
    (args.runs / "actors").mkdir(parents=True, exist_ok=True)
    record_path = args.runs / "train.json"
    record = json.loads(record_path.read_text()) if record_path.exists() else {}
    osrl = version("osrl-lib")
    example = torch.zeros(1, plan["state_dim"])
    for p in plan["peers"]:
        if args.only and p["name"] not in args.only:
            continue
        for seed in plan["seeds"]:
            out = actor_path(args.runs, p["name"], seed)
            key = f"{p['name']}_seed{seed}"
            made_by = plan_key(plan, p)
            if out.exists() and record.get(key, {}).get("plan") == made_by:
                continue
            torch.manual_seed(seed)
            np.random.seed(seed)
            start = time.perf_counter()
            actor, info = TRAIN[p["algorithm"]](data, plan, p, seed)
            seconds = time.perf_counter() - start
            actor.eval()
            scripted = torch.jit.trace(actor, example)
            meta = {**p, "seed": seed, "seconds": seconds, "osrl_lib": osrl,
                    "torch": torch.__version__, "cost_limit": plan["cost_limit"],
                    "episode_len": plan["episode_len"], "action_low": plan["action_low"],
                    "action_high": plan["action_high"], "dataset": plan.get("dataset"),
                    **info}  # fmt: skip
            tmp = out.with_suffix(".tmp")
            torch.jit.save(scripted, str(tmp), _extra_files={"safe_bc.json": json.dumps(meta)})
            tmp.replace(out)
            record[key] = {"peer": p["name"], "seed": seed, "updates": p["updates"],
                           "osrl_updates": p["osrl_updates"], "seconds": seconds,
                           "seconds_per_update": seconds / p["updates"], "plan": made_by,
                           **info}  # fmt: skip
            record_path.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
            each = seconds / p["updates"] * 1000
            print(
                f"{key}: {p['updates']} updates in {seconds:.1f} s ({each:.1f} ms each)", flush=True
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
