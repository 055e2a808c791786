"""The settings of a self-imitation run, its push specs and fixed names (stdlib only, so that
a study file or the CLI reads :class:`SelfImproveConfig` without importing torch or Ray)."""

from __future__ import annotations

import math
import re
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal, get_args

from safe_bc.handover import HandoverConfig
from safe_bc.methods.layout import DONE, IDENTITY, POLICY, round_dir  # noqa: F401 (the run folder)

KeepUnit = Literal["episode", "segment"]
KeptIn = Literal["rest", "zone", "critical"]
KeepAgainst = Literal["agent", "expert"]
Forward = Literal["rows", "batched"]
"""How lockstep runs reach the agent's net: the values of ``safe_bc.policy.LockstepForward``
(named here so that this module stays stdlib only)."""

FORMAT = "safe_bc.selfimprove/2"
"""Run-folder format (2: rounds and the start's validation record their env steps)."""
KEPT = "kept.npz"
FRAMES = "frames.npy"
"""A round's training frames while it trained (``frames_on_disk``, deleted after), before
the kept-frame store (:mod:`safe_bc.methods.selfimprove.store`): no longer written."""
START_VALIDATION = "start_validation.json"
CURVE = "curve.parquet"
"""A run's learning curve (``SelfImproveResult.history``, one row per round after the start's),
rewritten after every round, with TensorBoard scalars ``selfimprove/<column>`` beside it."""

LOOP_PUSHES: dict[str, tuple[str, ...]] = {
    "carracing": ("1+0.03", "1+0.05", "2*0.9", "2*0.8", "2*0.5"),
    "rehab": ("0+0.05", "0-0.05", "1+0.05", "1-0.05"),
}
"""The pushes the selection tables started from (their ``defaults`` rows). CarRacing: gas
+0.03 / +0.05, brake x0.9 / x0.8 / x0.5 (the loop a user measured by hand); rehab:
intensity and duration +-0.05."""


class _TaskDefaults(Mapping[str, dict[str, Any]]):
    """Read-only: each registered task's ``TaskSpec.selfimprove``, read from its record."""

    @staticmethod
    def _table() -> dict[str, dict[str, Any]]:
        from safe_bc.tasks.registry import TASKS

        return {name: dict(spec.selfimprove) for name, spec in TASKS.items() if spec.selfimprove}

    def __getitem__(self, task: str) -> dict[str, Any]:
        return self._table()[task]

    def __iter__(self) -> Iterator[str]:
        return iter(self._table())

    def __len__(self) -> int:
        return len(self._table())


TASK_DEFAULTS: Mapping[str, dict[str, Any]] = _TaskDefaults()
"""Each registered task's values for the fields a :class:`SelfImproveConfig` leaves at
``None`` (its ``TaskSpec.selfimprove``, read from the task's record), each chosen by
its selection table (3 training seeds x 50 selection tracks or 200 selection patients; the
rule of the tables' report step, ``safe_bc/methods/selfimprove/choice.py``: among the rows with
a reliable reward gain over the start, the fewest episodes beyond d_s). CarRacing: 4 rounds
of the loop's pushes at half size (offsets halved, scales halfway to 1;
``results/selfimprove/carracing/rounds_choice.md``), kept rows in the rest pool (``choice.md``:
no safety filter did better than the defaults). Rehab: kept rows in T_eps
(``results/selfimprove/rehab/choice.md``), 2 rounds of the loop's pushes."""

_TERM = re.compile(r"^(\d+)([+*-])([0-9.eE+-]+)$")


def parse_push(spec: str) -> tuple[tuple[int, str, float], ...]:
    """The terms of a push spec: ``"<dim><op><value>"`` joined by ``,``; ``op`` is ``+`` or
    ``-`` (an offset added to the executed action's dimension ``dim``) or ``*`` (a scale).

    >>> parse_push("1+0.03"), parse_push("2*0.5,0-0.1")
    (((1, '+', 0.03),), ((2, '*', 0.5), (0, '+', -0.1)))
    """
    terms = []
    for part in spec.replace(" ", "").split(","):
        m = _TERM.match(part)
        try:
            value = float(m.group(3)) if m else math.nan
        except ValueError:
            value = math.nan
        if m is None or not math.isfinite(value):
            raise ValueError(f"push term must read like '1+0.03', '2*0.9' or '0-0.1', got {part!r}")
        dim, op = int(m.group(1)), m.group(2)
        terms.append((dim, "+", -value) if op == "-" else (dim, op, value))
    return tuple(terms)


@dataclass(frozen=True)
class SelfImproveConfig:
    """One self-imitation run: push the agent's own rollouts, keep the safe better ones,
    retrain on demonstrations plus kept data, accept the round's agent by the keep rule,
    repeat. The safety choices (keep unit, margin, back-off, where kept rows go) were measured
    one at a time on CarRacing selection tracks and the defaults kept
    (``results/selfimprove/carracing/choice.md``), then rounds and push sizes
    (``rounds_choice.md``); the rehab table chose ``kept_in="critical"``
    (``results/selfimprove/rehab/choice.md``). Fields left at ``None`` take the task's
    measured values (:data:`TASK_DEFAULTS`, :meth:`for_task`). The same CarRacing table
    measured ``alpha=0.5`` (no reliable gain) and ``beyond_limit=0.05`` on 64 validation
    tracks (the same rounds accepted as the defaults'): neither moved a default."""

    rounds: int | None = None
    """Rounds of roll-out, filter, retraining and keep rule (``None``: the task's; CarRacing 4,
    rehab 2)."""
    tracks_per_round: int = 24
    """Training tracks (patients) per round (:func:`safe_bc.methods.queries.config.track_seeds`,
    shared with the query stage): each is run once unperturbed (the reference) and once per
    push. 24 is the user's loop."""
    pushes: tuple[str, ...] | None = None
    """Executed-action pushes, one rollout each (:func:`parse_push`: ``"1+0.03"`` adds 0.03
    to dimension 1, ``"2*0.9"`` scales dimension 2; the result is clipped to the action
    bounds). The agent's own action is recorded, the executed one is the label of kept rows.
    ``None``: the task's (:data:`TASK_DEFAULTS`)."""
    keep_unit: KeepUnit = "episode"
    """``"episode"``: a pushed episode is kept whole when none of its scored states (nor the
    last step's outcome) is beyond ``d_s - margin`` and its reward beats the reference run's;
    ``"segment"``: every window of :attr:`segment_steps` steps that stays inside
    ``d_s - margin`` and beats the reference over the same steps is kept."""
    segment_steps: int = 50
    """Window length of ``keep_unit="segment"`` (steps; windows start at 0, do not overlap)."""
    margin: float = 0.0
    """Kept data stay at least this far inside ``d_s`` (cost units, every dimension): a kept
    state has ``c_s <= d_s - margin``. The user's loop had fewer crossings with 1 px."""
    backoff: bool = True
    """No push in states of the critical zone (``c_s >= d_s - backoff_eps``): the agent's own
    action is executed there."""
    backoff_eps: float | None = None
    """Width of the back-off zone in cost units; ``None``: the selection's eps."""
    kept_in: KeptIn | None = None
    """Where kept rows go in the alpha mix: ``"rest"`` (the rest pool only: ``T_eps`` stays
    the demonstrations' critical rows), ``"zone"`` (by the selection's rule, like a
    demonstration row) or ``"critical"`` (every kept row joins ``T_eps``). ``None``: the
    task's (CarRacing ``"rest"``, rehab ``"critical"``)."""
    alpha: float | None = None
    """Fraction of every retraining batch drawn from ``T_eps`` (the paper's alpha mix, which
    carries the expert's behaviour near the limit into each retraining); ``None``: the start's
    run config's alpha. Only the retraining changes: the start and its ``T_eps`` stay."""
    beyond_limit: float = 0.1
    """Keep rule: a round's agent is accepted only when the one-sided 95% Clopper-Pearson upper
    bound on its share of validation episodes beyond ``d_s`` is below this, and its mean
    validation reward is not below the previous agent's; else the previous agent stays."""
    validation_episodes: int = 32
    """Validation tracks of the keep rule (the improvement stage's validation seeds, disjoint
    from training and held-out evaluation tracks)."""
    batches: int | None = None
    """BC batches of each retraining (``None``: the run config's ``bc.train.batches``)."""
    max_steps: int | None = None
    """Step cap per episode, rollouts and validation (``None``: the env's time limit)."""
    keep_against: KeepAgainst = "agent"
    """Whose run on the same track a pushed run must beat to be kept: ``"agent"`` (the
    agent's own unperturbed run) or ``"expert"`` (the demonstrations' expert's run: only
    driving better than the teacher is kept)."""
    keep_best: int | None = None
    """Keep at most this many pushed runs per track, those with the highest rewards among
    the ones the keep unit keeps (``None``: every one)."""
    handover: HandoverConfig | None = None
    """A :class:`safe_bc.handover.HandoverConfig`: the pushed and reference runs drive under
    this critical-zone handover (the expert acts, unpushed, where the handover defers; its
    actions label those rows), so a push is tried only where the agent drives. ``None``: the
    agent alone."""
    workers: int = 0
    """Rollout actors (Ray); 0 rolls out in this process. Results do not depend on it."""
    lockstep_envs: int = 8
    """Envs each rollout process steps its runs in together (training runs and validation
    episodes, one ``act_slots`` call per step; ``make bench``'s ``selfimprove`` case times it).
    With ``lockstep_forward="rows"`` results do not depend on it."""
    lockstep_forward: Forward = "rows"
    """``"rows"``: the net computes each lockstep run's row on its own, so every run is the
    one-env run bit for bit on any CPU; ``"batched"``: one forward pass over the running runs
    (faster per step; the same runs again for the same seeds and ``lockstep_envs`` on one
    machine type, not the one-env runs: ``safe_bc.policy.LockstepForward``)."""
    seed: int = 0
    """Picks the rollout tracks; the study stage sets it to the training seed."""

    def __post_init__(self) -> None:
        if self.keep_unit not in get_args(KeepUnit):
            raise ValueError(
                f"keep_unit must be one of {get_args(KeepUnit)}, got {self.keep_unit!r}"
            )
        if self.kept_in is not None and self.kept_in not in get_args(KeptIn):
            raise ValueError(f"kept_in must be one of {get_args(KeptIn)}, got {self.kept_in!r}")
        for name in ("tracks_per_round", "segment_steps", "validation_episodes"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("rounds", "batches", "max_steps"):
            value = getattr(self, name)
            if value is not None and int(value) < 1:
                raise ValueError(f"{name} must be >= 1 or None, got {value}")
        for name in ("margin", "backoff_eps"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")
        if self.alpha is not None and not 0 <= self.alpha <= 1:
            raise ValueError(f"alpha must be in [0, 1] or None, got {self.alpha}")
        if not 0 < self.beyond_limit <= 1:
            raise ValueError(f"beyond_limit must be in (0, 1], got {self.beyond_limit}")
        if self.pushes is not None:
            object.__setattr__(self, "pushes", tuple(self.pushes))
            if not self.pushes:
                raise ValueError("pushes must name at least one push (or be None)")
            for spec in self.pushes:
                parse_push(spec)
        if self.keep_against not in get_args(KeepAgainst):
            raise ValueError(
                f"keep_against must be one of {get_args(KeepAgainst)}, got {self.keep_against!r}"
            )
        if self.keep_best is not None and int(self.keep_best) < 1:
            raise ValueError(f"keep_best must be >= 1 or None, got {self.keep_best}")
        if self.handover is not None and not isinstance(self.handover, HandoverConfig):
            raise ValueError(f"handover must be a HandoverConfig or None, got {self.handover!r}")
        if self.lockstep_forward not in get_args(Forward):
            raise ValueError(
                f"lockstep_forward must be one of {get_args(Forward)}, "
                f"got {self.lockstep_forward!r}"
            )
        if int(self.lockstep_envs) < 1:
            raise ValueError(f"lockstep_envs must be >= 1, got {self.lockstep_envs}")
        if self.workers < 0 or self.seed < 0:
            raise ValueError(f"workers and seed must be >= 0, got {self.workers}, {self.seed}")

    def for_task(self, task: str) -> SelfImproveConfig:
        """This config with ``task``'s values (:data:`TASK_DEFAULTS`) for the fields left at
        ``None``; what a run executes and records."""
        unset = [k for k in ("rounds", "pushes", "kept_in") if getattr(self, k) is None]
        if unset and task not in TASK_DEFAULTS:
            raise ValueError(
                f"task {task!r} has no self-imitation defaults; set SelfImproveConfig."
                + ", .".join(unset)
            )
        return replace(self, **{k: TASK_DEFAULTS[task][k] for k in unset})

    @property
    def resolved(self) -> bool:
        """Whether every task-dependent field is set (:meth:`for_task`)."""
        return None not in (self.rounds, self.pushes, self.kept_in)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able field dict."""
        out = asdict(self)
        if self.pushes is not None:
            out["pushes"] = list(self.pushes)
        if self.handover is not None:
            out["handover"] = self.handover.to_dict()
        return out

    def identity(self) -> dict[str, Any]:
        """The fields that change the run's data or weights (``workers`` does not); a field
        of :data:`UNSET_OMITTED` is left out while it has its neutral value, so a run's
        identity names only the options it uses."""
        out = self.to_dict()
        out.pop("workers")
        if self.lockstep_forward == "rows":  # the one-env runs whatever the pool's width
            out.pop("lockstep_envs")
        for name, neutral in UNSET_OMITTED.items():
            if out[name] == neutral:
                out.pop(name)
        return out


UNSET_OMITTED: dict[str, Any] = {
    "alpha": None,
    "keep_against": "agent",
    "keep_best": None,
    "handover": None,
    "lockstep_forward": "rows",
}
"""The options a run's identity names only when set (their neutral values: the start's alpha,
the agent's own run as the bar, every kept run, no handover, the one-env runs' rounding)."""
