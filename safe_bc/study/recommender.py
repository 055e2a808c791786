"""The study's deliverable: a recommender (an agent, its critical-zone handover to the expert,
the limits ``d_s`` and the demonstrations they came from), written to and loaded from one folder.

Layout of ``DIR`` (``results/<study>/recommender/``)::

    DIR/recommender.json   the card: task, env, d_s per dimension, handover, the
                           demonstrations' digest and collector settings, the training
                           seeds, the certificate, provenance
    DIR/seed_<k>/          the agent trained with seed k (a safe_bc checkpoint: weights.pt
                           and config.json, both checksummed)

>>> import safe_bc
>>> rec = safe_bc.load_recommender("results/default/recommender")  # doctest: +SKIP
>>> rec.reset(env)                                                 # doctest: +SKIP
>>> step = rec.step(obs, info, env)  # .action, .actor, .margin  # doctest: +SKIP
"""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from safe_bc.data.atomic import write_json_atomic
from safe_bc.handover import HandoverConfig

FORMAT = "safe_bc.recommender/2"
"""The format :func:`write_recommender` writes: the card carries :data:`CARD_SHA256`."""
UNSEALED = "safe_bc.recommender/1"
"""The format of a card written before cards were sealed: its d_s, handover and digest could be
edited unseen, so :func:`read_card` refuses it unless asked (``allow_unsealed=True``); every
committed card is sealed (``/2``)."""
FORMATS = (UNSEALED, FORMAT)
"""The formats a card may carry."""
CARD_SHA256 = "card_sha256"
"""Key in the card of the SHA-256 of the rest of it (sorted, compact JSON): an edited d_s,
handover or digest is refused."""
CARD = "recommender.json"
"""The card's file name."""
Actor = Literal["agent", "expert", "safest"]
"""Who chose a step's action: the agent; inside the handover's zone the expert (or, with a
capping handover, the agent bounded by the expert); or the task's safest action (a
``safest`` handover)."""


class RecommenderError(ValueError):
    """A recommender folder that is missing, damaged, or not for this task or data (one line)."""


@dataclass(frozen=True)
class Recommendation:
    """One step's recommendation."""

    action: np.ndarray
    """``(A,) float32``: the action to take."""
    actor: Actor
    """Who chose it (:data:`Actor`): ``"agent"``, or inside the handover zone ``"expert"``
    (with a capping handover: the expert's action bounded the agent's there) or ``"safest"``."""
    margin: dict[str, float]
    """Per safety dimension, ``d_s - c_s`` of the current state: how far the state is inside
    the expert's worst cost (negative: beyond ``d_s``); NaN on a step that is not scored."""
    scored: bool = True
    """Whether the state is scored against ``d_s`` (False on the env's warm-up steps, e.g.
    CarRacing's zoom-in frames, whose costs no crossing count reads)."""


@dataclass(frozen=True)
class RecommenderCard:
    """What a recommender is: the contents of ``recommender.json``."""

    task: str
    """The task's registry name (``carracing``, ``rehab``)."""
    env: dict[str, Any]
    """The environment's settings (``EnvConfig`` fields: id, renderer, ...)."""
    limits: dict[str, float]
    """``d_s`` per safety dimension, in the order of the env's costs."""
    handover: dict[str, Any] | None
    """The handover's settings (:class:`HandoverConfig`), ``None``: the agent acts alone."""
    expert: dict[str, Any]
    """The expert's configuration (the demonstrations' ``dataset.json`` record, with type)."""
    demos: dict[str, Any]
    """The demonstrations: ``digest`` (:func:`safe_bc.data.store.data_digest`), ``episodes``,
    ``collector`` (their collector settings), ``path`` where they were read."""
    seeds: list[int]
    """Training seeds; the agent of seed ``k`` is in ``seed_<k>/``; the first is the default."""
    run_config: dict[str, Any]
    """The agents' run configuration (the first seed's; the others differ in the seed only)."""
    source: dict[str, Any] = field(default_factory=dict)
    """Where it came from: study name, winner trial id, command, git revision, CPU."""
    certificate: dict[str, Any] = field(default_factory=dict)
    """What its fresh episodes showed (crossings, their bound, reward against the expert,
    deferred share, the tracks), empty when not certified."""
    format: str = FORMAT
    """The format tag."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-able fields."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], where: Any = CARD, *, allow_unsealed: bool = False
    ) -> RecommenderCard:
        """Inverse of :meth:`to_dict`; one-line error for a foreign, damaged or (unless
        ``allow_unsealed``) unsealed card."""
        if data.get("format") not in FORMATS:
            raise RecommenderError(f"{where}: not a safe_bc recommender card ({FORMAT})")
        if data.get("format") == UNSEALED and not allow_unsealed:
            raise RecommenderError(
                f"{where}: an unsealed card ({UNSEALED}: its d_s and handover are not checked); "
                "write the recommender again from its study, or load it with "
                "allow_unsealed=True"
            )
        if data.get("format") == FORMAT and data.get(CARD_SHA256) != card_digest(data):
            raise RecommenderError(
                f"{where}: the card does not match its {CARD_SHA256} (edited or damaged); "
                "write the recommender again from its study"
            )
        try:
            return cls(**{k: data[k] for k in cls.__dataclass_fields__ if k in data})
        except TypeError as e:
            raise RecommenderError(f"{where}: malformed recommender card ({e})") from None

    @property
    def handover_config(self) -> HandoverConfig | None:
        """The handover as a config (``None``: none)."""
        return None if self.handover is None else HandoverConfig.from_dict(self.handover)


def write_recommender(
    out: Path, card: RecommenderCard, agents: Mapping[int, tuple[Any, Any]]
) -> Path:
    """Write a recommender folder: ``agents`` maps each seed of ``card.seeds`` to its
    ``(BCNet, BCConfig)``. Built in a temporary sibling folder and renamed into place, so a
    reader sees the old recommender or the new one, never a mix."""
    from safe_bc.bc.checkpoint import save_checkpoint

    out = Path(out)
    if sorted(agents) != sorted(card.seeds):
        raise ValueError(f"agents for seeds {sorted(agents)}, the card names {card.seeds}")
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    try:
        for seed, (model, config) in agents.items():
            save_checkpoint(staging / f"seed_{seed}", model, config, extra={"seed": int(seed)})
        data = json.loads(json.dumps(card.to_dict(), default=str))
        write_json_atomic(staging / CARD, {**data, CARD_SHA256: card_digest(data)}, allow_nan=True)
        old = out.parent / f".{out.name}-old"
        if out.exists():
            shutil.rmtree(old, ignore_errors=True)
            out.rename(old)
        staging.rename(out)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out


def card_digest(data: Mapping[str, Any]) -> str:
    """SHA-256 of a card's JSON without its :data:`CARD_SHA256` (sorted keys, compact)."""
    import hashlib

    rest = {k: v for k, v in data.items() if k != CARD_SHA256}
    text = json.dumps(rest, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def read_card(path: Path, *, allow_unsealed: bool = False) -> RecommenderCard:
    """The card of the recommender folder ``path`` (an unsealed ``/1`` card only with
    ``allow_unsealed``)."""
    path = Path(path)
    file = path / CARD
    if not file.exists():
        raise RecommenderError(f"{path}: no recommender here (missing {CARD})")
    try:
        data = json.loads(file.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise RecommenderError(f"{file}: unreadable ({e})") from None
    return RecommenderCard.from_dict(data, file, allow_unsealed=allow_unsealed)


class Recommender:
    """An agent with its handover to the expert, stepping through one episode at a time.

    :meth:`reset` after ``env.reset``, then :meth:`step` with the current observation and
    ``info`` each step: the action to take, who chose it, and the margin to ``d_s``."""

    def __init__(self, card: RecommenderCard, agents: Mapping[int, tuple[Any, Any]]) -> None:
        self.card = card
        self.agents = dict(agents)
        self.dims = tuple(card.limits)
        self.limits = np.asarray([card.limits[d] for d in self.dims], np.float64)
        handover = card.handover_config
        safest = handover is not None and handover.fallback == "safest"
        self._zone_actor: Actor = "safest" if safest else "expert"
        self._policy: Any = None

    def source(self, seed: int | None = None) -> Any:
        """The policy source of seed ``seed``'s recommender (default: the first seed), for
        :func:`safe_bc.distributed.evaluate.evaluate`."""
        from safe_bc.rollout.collect import expert_config_from_dict
        from safe_bc.rollout.evaluate import NetSource
        from safe_bc.rollout.handover import handover_source

        seed = self.card.seeds[0] if seed is None else int(seed)
        if seed not in self.agents:
            raise RecommenderError(
                f"no agent of seed {seed}: the recommender has seeds {self.card.seeds}"
            )
        model, config = self.agents[seed]
        agent = NetSource.from_model(model, config)
        handover = self.card.handover_config
        if handover is None:
            return agent
        expert = expert_config_from_dict(self.card.expert)
        return handover_source(agent, handover, expert, self.limits, self.dims)

    def reset(
        self, env: gym.Env, rng: np.random.Generator | None = None, seed: int | None = None
    ) -> None:
        """Start an episode (after ``env.reset``) with seed ``seed``'s agent; an env of
        another task than the card's is refused in one line."""
        try:
            dims = tuple(env.get_wrapper_attr("safety_dims"))
        except AttributeError:
            dims = ()
        if dims != self.dims:
            raise RecommenderError(
                f"a recommender for {self.card.task!r} (safety dimensions "
                f"{', '.join(self.dims)}) cannot act in an env measuring "
                f"{', '.join(dims) or 'no safety dimensions'}: make the {self.card.task} env "
                "with safe_bc.tasks.make_env"
            )
        self._policy = self.source(seed).build()
        self._policy.reset(env, rng if rng is not None else np.random.default_rng(0))

    def step(self, obs: np.ndarray, info: Mapping[str, Any], env: gym.Env) -> Recommendation:
        """The recommendation for the state ``obs`` with ``info`` (its measured ``cost``)."""
        if self._policy is None:
            raise RuntimeError("call reset(env) before step()")
        see = getattr(self._policy, "see", None)
        if see is not None:
            see(info)
        action = np.asarray(self._policy.act(obs, env), np.float32)
        flags = getattr(self._policy, "flags", None)
        actor: Actor = self._zone_actor if flags and flags[-1] else "agent"
        cost = np.asarray(info["cost"], np.float64)
        scored = not bool(info.get("warmup", False))
        gap = self.limits - cost if scored else np.full(len(self.dims), np.nan)
        margin = {d: float(x) for d, x in zip(self.dims, gap, strict=True)}
        return Recommendation(action, actor, margin, scored)


def load_recommender(
    path: str | Path,
    *,
    task: str | None = None,
    demos: str | Path | None = None,
    allow_unsealed: bool = False,
    allow_uncertified: bool = False,
) -> Recommender:
    """Load the recommender folder ``path`` (every weight file checked against its checksum).

    Args:
        task: refuse it unless it was made for this task.
        demos: refuse it unless these demonstrations are the ones its ``d_s`` came from (same
            content digest).
        allow_unsealed: load a card written before cards were sealed (:data:`UNSEALED`).
        allow_uncertified: load the closest candidate of a study none of whose candidates met
            every constraint (its card's ``source["feasible"]`` is False).

    Raises:
        RecommenderError: one line naming the folder and the problem.
    """
    from safe_bc.bc import CheckpointError, load_checkpoint

    path = Path(path)
    card = read_card(path, allow_unsealed=allow_unsealed)
    if card.source.get("feasible") is False and not allow_uncertified:
        raise RecommenderError(
            f"{path}: an uncertified recommender (no candidate of study "
            f"{card.source.get('study')!r} met every constraint; this is the closest, "
            f"{card.source.get('winner')}); load it with allow_uncertified=True to inspect it"
        )
    if task is not None and task != card.task:
        raise RecommenderError(f"{path}: a recommender for {card.task!r}, not for {task!r}")
    if demos is not None:
        from safe_bc.data.store import data_digest

        digest = data_digest(Path(demos))
        if digest != card.demos.get("digest"):
            raise RecommenderError(
                f"{path}: made from other demonstrations than {demos} (digest "
                f"{card.demos.get('digest')}, these {digest}): its d_s is not theirs"
            )
    agents = {}
    for seed in card.seeds:
        try:
            agents[int(seed)] = load_checkpoint(path / f"seed_{seed}")
        except (CheckpointError, OSError) as e:
            raise RecommenderError(f"{path}: agent of seed {seed}: {e}") from None
    return Recommender(card, agents)
