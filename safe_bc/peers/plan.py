"""What ``make peers`` trains: OSRL's algorithms, their settings and the budgets used.

Pure data and arithmetic (no torch, no files): :data:`ALGORITHMS` holds, per peer, OSRL's own
settings (its repository's ``examples/configs/*_configs.py``: networks, learning rates, batch
size, reward and cost scales) and the number of updates ``make peers`` gives it beside OSRL's
default; :func:`training_plan` turns them and the demonstrations' shape into the plan the
peers' environment reads (``peers/osrl_train.py``); :func:`budget_lines` says in words what each
budget is and why it is not OSRL's.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

OSRL_VERSION = "0.1.0"
"""The osrl-lib release ``make peers-env`` installs (PyPI; with fast-safe-rl and dsrl 0.1.0)."""
OSRL_LICENCE = (
    "osrl-lib 0.1.0's wheel metadata says MIT; OSRL's GitHub repository has been Apache-2.0 "
    "since 2023-06 (safe_bc: Apache-2.0); DSRL's code is Apache-2.0. safe_bc does not copy "
    "OSRL's code: make peers installs it in an environment of its own and calls it."
)
"""The peers' licence, as the table states it."""


@dataclass(frozen=True)
class Peer:
    """One OSRL algorithm as ``make peers`` trains it."""

    name: str
    """The table's row (``BC-All``, ``BC-Safe``, ``COptiDICE``, ``CPQ``)."""
    algorithm: str
    """OSRL's class (``BC``, ``COptiDICE``, ``CPQ``); BC-All and BC-Safe are OSRL's ``BC`` with
    ``bc_mode`` ``all`` and ``safe`` (the episodes whose cost is within the budget)."""
    updates: int
    """Gradient updates ``make peers`` gives it (one batch each)."""
    osrl_updates: int
    """OSRL's default (``update_steps`` of its example config)."""
    settings: Mapping[str, Any] = field(default_factory=dict)
    """OSRL's example config's settings for it (passed to its model and trainer)."""

    def __post_init__(self) -> None:
        if self.updates < 1 or self.osrl_updates < 1:
            raise ValueError(f"{self.name}: updates must be >= 1")


ALGORITHMS: tuple[Peer, ...] = (
    Peer("BC-All", "BC", 5000, 300_000, {
        "bc_mode": "all", "a_hidden_sizes": [256, 256], "actor_lr": 1e-3, "batch_size": 512,
    }),
    Peer("BC-Safe", "BC", 5000, 300_000, {
        "bc_mode": "safe", "a_hidden_sizes": [256, 256], "actor_lr": 1e-3, "batch_size": 512,
    }),
    Peer("COptiDICE", "COptiDICE", 2000, 300_000, {
        "a_hidden_sizes": [256, 256], "c_hidden_sizes": [256, 256], "actor_lr": 1e-4,
        "critic_lr": 1e-4, "scalar_lr": 1e-4, "reward_scale": 0.1, "cost_scale": 1.0,
        "alpha": 0.5, "gamma": 0.99, "cost_ub_epsilon": 0.01, "f_type": "softchi",
        "num_nu": 2, "num_chi": 2, "batch_size": 512,
    }),
    Peer("CPQ", "CPQ", 300, 100_000, {
        "a_hidden_sizes": [300, 300], "c_hidden_sizes": [400, 400], "vae_hidden_sizes": 400,
        "actor_lr": 1e-4, "critic_lr": 1e-3, "alpha_lr": 1e-3, "vae_lr": 1e-3,
        "reward_scale": 0.1, "cost_scale": 1.0, "sample_action_num": 10, "gamma": 0.99,
        "tau": 0.005, "beta": 0.5, "num_q": 2, "num_qc": 2, "qc_scalar": 1.5,
        "batch_size": 512,
    }),
)  # fmt: skip
"""The peers, in the table's order. Settings: OSRL's example configs (BC, COptiDICE: the
``OfflineCarCircle-v0`` defaults; CPQ: ``offline-CarCircle-v0``'s)."""

CDT_NOTE = (
    "CDT (OSRL's Constrained Decision Transformer) is not trained: its rollout conditions each "
    "action on the returns-to-go of reward and cost, lowered by each step's reward and cost; "
    "safe_bc's rollout gives a policy each state's info (its costs, `see(info)`) but not the "
    "reward, so a CDT row needs the rollout to pass the reward too"
)
"""Why the table has no CDT row."""


def peer(name: str) -> Peer:
    """The peer called ``name`` (one line naming the peers if none is)."""
    for p in ALGORITHMS:
        if p.name == name:
            return p
    raise ValueError(f"unknown peer {name!r}; peers: {', '.join(p.name for p in ALGORITHMS)}")


def training_plan(
    *,
    state_dim: int,
    action_dim: int,
    episode_len: int,
    cost_limit: float,
    seeds: Sequence[int],
    peers: Sequence[Peer] = ALGORITHMS,
    scale: float = 1.0,
) -> dict[str, Any]:
    """The plan ``peers/osrl_train.py`` reads (plain JSON): the demonstrations' dimensions,
    the longest episode (OSRL's ``episode_len``, which sets CPQ's and COptiDICE's cost
    thresholds), the cost budget per episode, the training seeds and, per peer, its class,
    settings and updates (``scale`` multiplies every budget: a test's quick run).

    >>> p = training_plan(state_dim=4, action_dim=2, episode_len=30, cost_limit=1, seeds=[0],
    ...                   scale=0.001)
    >>> [(x["name"], x["updates"]) for x in p["peers"]]
    [('BC-All', 5), ('BC-Safe', 5), ('COptiDICE', 2), ('CPQ', 1)]
    """
    if state_dim < 1 or action_dim < 1 or episode_len < 1:
        raise ValueError("state_dim, action_dim and episode_len must be >= 1")
    if cost_limit < 0:
        raise ValueError(f"the cost budget must be >= 0, got {cost_limit}")
    if not seeds:
        raise ValueError("no training seed")
    return {
        "osrl_version": OSRL_VERSION,
        "state_dim": int(state_dim),
        "action_dim": int(action_dim),
        "episode_len": int(episode_len),
        "cost_limit": float(cost_limit),
        "seeds": [int(s) for s in seeds],
        "peers": [
            {**asdict(p), "settings": dict(p.settings), "updates": max(1, round(p.updates * scale))}
            for p in peers
        ],
    }


def budget_lines(trained: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """One line per peer: the updates it got against OSRL's default, the measured seconds per
    update and what OSRL's default would have cost (``trained``: per peer name, what
    ``osrl_train.py`` recorded: ``updates``, ``osrl_updates``, ``seconds_per_update``,
    ``seeds``).

    >>> line, = budget_lines({"CPQ": {"updates": 300, "osrl_updates": 100000,
    ...                               "seconds_per_update": 0.5, "seeds": 3}})
    >>> line.split(": ", 1)[1]
    "300 updates of 100,000 (OSRL's default), 0.5 s each: 13.9 h per seed at OSRL's, 41.7 h for 3"
    """
    out = []
    for name, t in trained.items():
        per = float(t["seconds_per_update"])
        full = per * int(t["osrl_updates"]) / 3600
        out.append(
            f"{name}: {int(t['updates']):,} updates of {int(t['osrl_updates']):,} (OSRL's "
            f"default), {per:.3g} s each: {full:.1f} h per seed at OSRL's, "
            f"{full * int(t['seeds']):.1f} h for {int(t['seeds'])}"
        )
    return out


__all__ = [
    "ALGORITHMS",
    "CDT_NOTE",
    "OSRL_LICENCE",
    "OSRL_VERSION",
    "Peer",
    "budget_lines",
    "peer",
    "training_plan",
]
