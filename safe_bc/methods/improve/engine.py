"""The learner: the start it improves (:func:`_load_start`) and :class:`Improver`, the run's
state with its rollouts and PPO-Lagrangian updates."""

from __future__ import annotations

import copy
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from safe_bc.bc.checkpoint import CheckpointError, load_checkpoint, read_checkpoint_meta
from safe_bc.bc.config import BCConfig
from safe_bc.bc.net import BCNet, ModelSpec
from safe_bc.bc.preprocess import preprocess
from safe_bc.bc.train import BatchBuilder
from safe_bc.methods.improve.config import FORMAT, ROLLOUT_RETRIES, ImproveConfig
from safe_bc.methods.improve.envs import (
    EnvGroupFactory,
    EnvsLostError,
    LocalEnvs,
    Rollout,
    train_env_seed,
    validation_seeds,
)
from safe_bc.methods.improve.nets import GaussianActor, gae, make_critic, multiplier_update
from safe_bc.methods.improve.shield import Shield
from safe_bc.metrics import excursion, violations
from safe_bc.selection import CriticalZone, SelectionConfig


@dataclass
class _Start:
    """What the start checkpoint fixes: its net and configs, the demonstrations, the limits."""

    model: BCNet
    config: BCConfig
    env_id: str
    demos_path: Path
    limits: np.ndarray
    selection: SelectionConfig


def _start_meta(start: Path, demos: Path | None) -> tuple[dict[str, Any], Path]:
    """The start checkpoint's metadata and the demonstrations the run uses (``demos``, else
    the start's own); reads ``config.json`` only."""
    meta = read_checkpoint_meta(start)
    extra = meta.get("extra", {})
    if "env_id" not in extra:
        raise ValueError(f"{start}: no env_id in the checkpoint; train it with safe-bc train")
    return meta, Path(demos if demos is not None else extra["demos"])


def _check_start_fits(start: Path, demos: Path | None) -> None:
    """Before anything is loaded or written: the start's net fits the task its config names,
    and the demonstrations are of that task (one-line ``ValueError`` otherwise)."""
    from safe_bc.data.store import read_meta
    from safe_bc.tasks import check_net_fits_task

    meta, demos_path = _start_meta(start, demos)
    env_id = meta["extra"]["env_id"]
    try:
        spec = ModelSpec.from_dict(meta["spec"])
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"malformed spec in {start / 'config.json'}: {e!r}") from None
    check_net_fits_task(spec.obs_shape, spec.action_dim, env_id, start)
    demos_env = read_meta(demos_path).env_id
    if demos_env != env_id:
        raise ValueError(
            f"--demos {demos_path} holds {demos_env} demonstrations but the start {start} was "
            f"trained on {env_id}; pass demonstrations of {env_id} (default: the start's own)"
        )


def _load_start(start: Path, demos: Path | None) -> tuple[_Start, Any]:
    from safe_bc.data.store import load_demonstrations, read_table

    meta, demos_path = _start_meta(start, demos)
    extra = meta["extra"]
    model, cfg = load_checkpoint(start)
    if cfg.preprocess.frame_stack != 1:
        raise ValueError("improvement supports frame_stack = 1 starts only")
    data = load_demonstrations(demos_path)
    _, sel_meta = read_table(start / "selection.parquet")
    selection = SelectionConfig(**sel_meta["config"])
    s = _Start(model, cfg, extra["env_id"], demos_path, data.limits, selection)
    return s, data


class Improver:
    """The run's state and its two steps, :meth:`rollout` and :meth:`update`."""

    def __init__(
        self,
        start: _Start,
        demos: Any,
        config: ImproveConfig,
        envs: EnvGroupFactory = LocalEnvs,
    ) -> None:
        from safe_bc.methods.experiment import select_for
        from safe_bc.tasks import task_defaults, task_of

        config = config.for_margin(task_defaults(task_of(start.env_id)).cost_margin)
        self.cfg, self.start = config, start
        self.pre_cfg = start.config.preprocess
        self.imitation = copy.deepcopy(start.model).eval()
        for p in self.imitation.parameters():
            p.requires_grad_(False)
        self.actor = GaussianActor(copy.deepcopy(start.model).train(), config.init_std)
        torch.manual_seed(config.seed)
        self.critic_r = make_critic(start.model, config.critic_hidden)
        self.critic_c = make_critic(start.model, config.critic_hidden)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=config.lr)
        critic_params = [*self.critic_r.parameters(), *self.critic_c.parameters()]
        self.critic_opt = torch.optim.Adam(critic_params, lr=config.critic_lr)
        self.rng = np.random.default_rng([config.seed, 1])
        self.gen = torch.Generator().manual_seed(config.seed)
        self.lam = config.lambda_init if config.lagrangian else 0.0
        self.iteration = self.episodes = self.env_steps = 0
        self.history: list[dict[str, float]] = []
        self.best: tuple[int, float, dict[str, torch.Tensor]] | None = None
        """``(iteration, validation reward, mean-net weights)`` of the best feasible policy."""

        eps = start.selection.eps if config.eps is None else config.eps
        zone = CriticalZone(start.limits, float(eps), start.selection.combine)
        self.shield = Shield(zone, start.env_id)
        self.limits = start.limits
        self.low = np.asarray(start.model.spec.action_low, np.float32)
        self.high = np.asarray(start.model.spec.action_high, np.float32)
        n_envs = min(config.n_envs, max(config.episodes_per_iter, config.eval_episodes))
        self.envs = envs(start.env_id, n_envs)
        self.demos = BatchBuilder(demos, self.pre_cfg)
        self.sampler = select_for(demos, start.selection).sampler(config.anchor_batch, self.rng)

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "iteration": self.iteration,
            "episodes": self.episodes,
            "env_steps": self.env_steps,
            "lambda": self.lam,
            "actor": self.actor.state_dict(),
            "critic_r": self.critic_r.state_dict(),
            "critic_c": self.critic_c.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "rng": json.dumps(self.rng.bit_generator.state),
            "gen": self.gen.get_state(),
            "history": json.dumps(self.history),
            "best": None if self.best is None else list(self.best),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.iteration, self.episodes = state["iteration"], state["episodes"]
        self.env_steps, self.lam = state["env_steps"], state["lambda"]
        self.actor.load_state_dict(state["actor"])
        self.critic_r.load_state_dict(state["critic_r"])
        self.critic_c.load_state_dict(state["critic_c"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.rng.bit_generator.state = json.loads(state["rng"])  # in place: the sampler shares it
        self.gen.set_state(state["gen"])
        self.history = json.loads(state["history"])
        self.best = None if state["best"] is None else tuple(state["best"])

    # ------------------------------------------------------------------ rollouts
    def _cost_signal(self, costs: np.ndarray) -> float:
        limit = self.limits - self.cfg.cost_margin
        if self.cfg.cost_signal == "indicator":
            return float(violations(costs[None], limit)[0])
        return float(excursion(costs[None], limit)[0])

    def rollout(self, seeds: list[int], *, stochastic: bool = True) -> Rollout:
        """Run one complete episode per seed (lockstep waves of ``n_envs``).

        Stochastic rollouts sample the Gaussian; deterministic ones take its mean. With the
        shield on, critical states get the frozen start's action either way.
        """
        cfg = self.cfg
        episodes: list[dict[str, list]] = []
        for w in range(0, len(seeds), len(self.envs)):
            wave = seeds[w : w + len(self.envs)]
            obs = self.envs.reset(wave)
            trajs: list[dict[str, list]] = [{} for _ in wave]
            last_obs: list[np.ndarray | None] = [None] * len(wave)
            alive = list(range(len(wave)))
            while alive:
                o = np.stack([obs[i] for i in alive])
                x = preprocess(o, self.pre_cfg)
                with torch.no_grad():
                    dist = self.actor.dist(x)
                    a = dist.mean
                    if stochastic:
                        a = a + dist.stddev * torch.randn(a.shape, generator=self.gen)
                    logp = dist.log_prob(a).sum(-1)
                    shielded = np.zeros(len(alive), bool)
                    if cfg.shield:
                        shielded = self.shield.critical(o)
                        if shielded.any():
                            mask = torch.as_tensor(shielded)
                            a[mask] = self.imitation(x[mask])
                    v_r = self.critic_r(x)[:, 0] if stochastic else torch.zeros(len(alive))
                    v_c = self.critic_c(x)[:, 0] if stochastic else torch.zeros(len(alive))
                actions = a.numpy()
                executed = np.clip(actions, self.low, self.high)
                still = []
                stepped = self.envs.step(alive, executed)
                for j, (i, (nobs, r, term, trunc, cost)) in enumerate(
                    zip(alive, stepped, strict=True)
                ):
                    row = {
                        "obs": o[j], "action": actions[j], "logp": float(logp[j]),
                        "shielded": bool(shielded[j]), "reward": r,
                        "cost": self._cost_signal(cost),
                        "violation": bool(violations(cost[None], self.limits)[0]),
                        "v_r": float(v_r[j]), "v_c": float(v_c[j]),
                    }  # fmt: skip
                    for k, v in row.items():
                        trajs[i].setdefault(k, []).append(v)
                    obs[i] = nobs
                    if term or trunc:
                        last_obs[i] = None if term else nobs
                    else:
                        still.append(i)
                alive = still
            for i, t in enumerate(trajs):
                t["bootstrap"] = last_obs[i]
            episodes.extend(trajs)
        return self._flatten(episodes, with_values=stochastic)

    def _flatten(self, episodes: list[dict[str, Any]], with_values: bool) -> Rollout:
        cfg = self.cfg
        adv_r, ret_r, adv_c, ret_c = [], [], [], []
        for t in episodes:
            last_r = last_c = 0.0
            if t["bootstrap"] is not None and with_values:
                with torch.no_grad():
                    x = preprocess(np.asarray(t["bootstrap"])[None], self.pre_cfg)
                    last_r, last_c = float(self.critic_r(x)[0, 0]), float(self.critic_c(x)[0, 0])
            for rew, val, last, advs, rets in (
                ("reward", "v_r", last_r, adv_r, ret_r),
                ("cost", "v_c", last_c, adv_c, ret_c),
            ):
                a, r = gae(np.asarray(t[rew]), np.asarray(t[val]), last, cfg.gamma, cfg.gae_lambda)
                advs.append(a)
                rets.append(r)

        def cat(key: str, dtype: Any) -> np.ndarray:
            return np.concatenate([np.asarray(t[key], dtype) for t in episodes])

        return Rollout(
            obs=np.concatenate([np.stack(t["obs"]) for t in episodes]),
            actions=np.concatenate([np.stack(t["action"]) for t in episodes]).astype(np.float32),
            logp=cat("logp", np.float32),
            shielded=cat("shielded", bool),
            rewards=cat("reward", np.float64),
            costs=cat("cost", np.float64),
            violation=cat("violation", bool),
            adv_r=np.concatenate(adv_r),
            ret_r=np.concatenate(ret_r),
            adv_c=np.concatenate(adv_c),
            ret_c=np.concatenate(ret_c),
            episode_return=np.array([np.sum(t["reward"]) for t in episodes]),
            episode_cost=np.array([np.sum(t["cost"]) for t in episodes]),
            episode_violations=np.array([np.sum(t["violation"]) for t in episodes], np.int64),
        )

    # ------------------------------------------------------------------ learning
    def update(self, ro: Rollout) -> dict[str, float]:
        """Multiplier step, then PPO epochs on the policy (after the warm-up) and critics."""
        cfg = self.cfg
        if cfg.lagrangian:
            cost = float(ro.episode_cost.mean())
            self.lam = multiplier_update(
                self.lam, cost, cfg.cost_budget, cfg.lambda_lr, cfg.lambda_max
            )
        own = ~ro.shielded
        ref = own if own.any() else np.ones(len(ro), bool)
        adv_r = (ro.adv_r - ro.adv_r[ref].mean()) / (ro.adv_r[ref].std() + 1e-8)
        adv_c = ro.adv_c - ro.adv_c[ref].mean()
        adv = (adv_r - self.lam * adv_c) / (1.0 + self.lam)

        x_all = preprocess(ro.obs, self.pre_cfg)
        t = {
            "act": torch.as_tensor(ro.actions), "logp": torch.as_tensor(ro.logp),
            "adv": torch.as_tensor(adv, dtype=torch.float32),
            "ret_r": torch.as_tensor(ro.ret_r, dtype=torch.float32),
            "ret_c": torch.as_tensor(ro.ret_c, dtype=torch.float32),
            "own": torch.as_tensor(own, dtype=torch.float32),
        }  # fmt: skip
        with torch.no_grad():
            start_mean = self.imitation(x_all)
        policy_on = self.iteration >= cfg.critic_warmup
        sums: dict[str, list[float]] = {}
        stop = False
        for _ in range(cfg.update_epochs):
            perm = self.rng.permutation(len(ro))
            kls = []
            for lo in range(0, len(ro), cfg.minibatch_size):
                idx = torch.as_tensor(perm[lo : lo + cfg.minibatch_size])
                x = x_all[idx]
                v_loss = (self.critic_r(x)[:, 0] - t["ret_r"][idx]).square().mean()
                v_loss = v_loss + (self.critic_c(x)[:, 0] - t["ret_c"][idx]).square().mean()
                self.critic_opt.zero_grad(set_to_none=True)
                v_loss.backward()
                nn.utils.clip_grad_norm_(
                    [*self.critic_r.parameters(), *self.critic_c.parameters()], cfg.max_grad_norm
                )
                self.critic_opt.step()
                sums.setdefault("value_loss", []).append(v_loss.item())
                if not policy_on:
                    continue
                dist = self.actor.dist(x)
                logp = dist.log_prob(t["act"][idx]).sum(-1)
                log_ratio = logp - t["logp"][idx]
                ratio = log_ratio.exp()
                a, w = t["adv"][idx], t["own"][idx]
                clipped = ratio.clamp(1 - cfg.clip_coef, 1 + cfg.clip_coef)
                n_own = w.sum().clamp(min=1.0)
                pg_loss = -(torch.min(ratio * a, clipped * a) * w).sum() / n_own
                entropy = (dist.entropy().sum(-1) * w).sum() / n_own
                anchor = self._anchor_loss(dist, start_mean[idx])
                loss = pg_loss + cfg.anchor_coef * anchor - cfg.ent_coef * entropy
                self.actor_opt.zero_grad(set_to_none=True)
                loss.backward()
                nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.max_grad_norm)
                self.actor_opt.step()
                with torch.no_grad():
                    kls.append(float((((ratio - 1) - log_ratio) * w).sum() / n_own))
                for k, v in (("pg_loss", pg_loss), ("anchor_loss", anchor), ("entropy", entropy)):
                    sums.setdefault(k, []).append(float(v.detach()))
            if kls:
                sums.setdefault("approx_kl", []).append(float(np.mean(kls)))
                stop = cfg.target_kl is not None and np.mean(kls) > cfg.target_kl
            if stop:
                break
        return {k: float(np.mean(v)) for k, v in sums.items()}

    def _anchor_loss(self, dist: torch.distributions.Normal, start_mean: torch.Tensor) -> Any:
        cfg = self.cfg
        if cfg.anchor == "bc":
            rows = self.sampler.sample()
            pred = self.actor.mean_net(self.demos.inputs(rows))
            return (pred - self.demos.targets(rows)).square().sum(-1).mean()
        if cfg.anchor == "kl":
            start = torch.distributions.Normal(
                start_mean, torch.full_like(start_mean, cfg.init_std)
            )
            return torch.distributions.kl_divergence(dist, start).sum(-1).mean()
        return torch.zeros(())

    def _retrying(self, rollout: Callable[..., Rollout], *args: Any, **kw: Any) -> Rollout:
        """``rollout(*args, **kw)``, run again from the same noise state when the env group
        loses envs (up to :data:`ROLLOUT_RETRIES` times): the retry is bit-identical to an
        undisturbed rollout."""
        noise = self.gen.get_state()
        for attempt in range(ROLLOUT_RETRIES + 1):
            try:
                return rollout(*args, **kw)
            except EnvsLostError:
                if attempt == ROLLOUT_RETRIES:
                    raise
                self.gen.set_state(noise)
                self.envs.restart()
        raise AssertionError("unreachable")

    # ------------------------------------------------------------------ one iteration
    def iterate(self) -> dict[str, float]:
        """Collect, update, (validate); returns the iteration's history row."""
        cfg = self.cfg
        t0 = time.perf_counter()
        first = self.episodes
        seeds = [train_env_seed(cfg.seed, first + k) for k in range(cfg.episodes_per_iter)]
        ro = self._retrying(self.rollout, seeds)
        self.episodes += len(seeds)
        self.env_steps += len(ro)
        stats = self.update(ro)
        self.iteration += 1
        row: dict[str, float] = {
            "iteration": self.iteration,
            "env_steps": self.env_steps,
            "episodes": self.episodes,
            "train_reward": float(ro.episode_return.mean()),
            "train_violation_steps": float(ro.episode_violations.mean()),
            "train_any_violation": float((ro.episode_violations > 0).mean()),
            "train_episode_cost": float(ro.episode_cost.mean()),
            "shielded_share": float(ro.shielded.mean()),
            "lambda": self.lam,
            "action_std": float(self.actor.log_std.detach().exp().mean()),
            **{k: stats.get(k, float("nan")) for k in
               ("value_loss", "pg_loss", "anchor_loss", "entropy", "approx_kl")},
        }  # fmt: skip
        row.update(val_reward=float("nan"), val_violation_steps=float("nan"),
                   val_any_violation=float("nan"), val_env_steps=0)  # fmt: skip
        last = self.iteration == cfg.iterations
        if cfg.eval_every and (self.iteration % cfg.eval_every == 0 or last):
            val = self._retrying(self.rollout, validation_seeds(cfg.eval_episodes),
                                 stochastic=False)  # fmt: skip
            row.update(
                val_reward=float(val.episode_return.mean()),
                val_violation_steps=float(val.episode_violations.mean()),
                val_any_violation=float((val.episode_violations > 0).mean()),
                val_env_steps=len(val),
            )
            feasible = not val.episode_violations.any()
            if feasible and (self.best is None or row["val_reward"] > self.best[1]):
                weights = copy.deepcopy(self.actor.mean_net.state_dict())
                self.best = (self.iteration, row["val_reward"], weights)
        row["seconds"] = time.perf_counter() - t0
        self.history.append(row)
        return row
