"""The critical-zone handover's settings (stdlib only: study files, task records and the CLI read
it without torch or Ray).

The handover turns an agent into a recommender that never acts where the expert's own limit is
close: the expert acts wherever the measured cost, extrapolated ``lookahead`` steps along its
last change, is within ``width`` (or the dimension's own entry of ``widths``) of ``d_s`` in
some dimension, and for ``hold`` more steps after a zone step of the ``hold_on`` dimensions.
With ``fallback="cap"`` the expert's action does not replace the agent's but bounds it: each
action component goes no further than the expert's in the direction that raises the costs; with
``fallback="safest"`` the zone's action is the task's safest one (each component at its bound in
the safer direction), whatever the agent or the expert would do. Two restarts act wherever the
cost is: ``stall`` (the costs stood still, a car at rest) and ``pace`` (the car's speed stayed
below a threshold, a car crawling), each for its own number of expert steps.
:class:`safe_bc.rollout.handover.DeferringPolicy` carries it out.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from typing import Any, Literal, get_args

Fallback = Literal["expert", "cap", "safest"]
"""What acts in the zone: ``expert``, the expert's action; ``cap``, the agent's action capped
per component by the expert's in the task's safer direction (``TaskSpec.safer_actions``);
``safest``, each action component at its bound in that direction."""
FALLBACKS: tuple[str, ...] = get_args(Fallback)
"""The fallbacks a handover accepts (:data:`Fallback`'s values)."""


@dataclass(frozen=True)
class HandoverConfig:
    """Where the expert takes over from the agent."""

    width: float
    """``w``, in the cost's units: the expert acts where ``c_s >= d_s - w`` in some dimension."""
    lookahead: int = 0
    """Steps the cost is extrapolated for the zone test (0: the measured cost itself)."""
    hold: int = 0
    """Steps the expert keeps acting after a zone step of the ``hold_on`` dimensions."""
    hold_on: tuple[str, ...] = ()
    """Safety dimensions whose zone steps start a hold (empty: any dimension)."""
    widths: tuple[tuple[str, float], ...] = ()
    """``(dimension, width)`` pairs overriding ``width`` for those safety dimensions (tasks
    whose costs have different units per dimension); empty: ``width`` everywhere."""
    fallback: Fallback = "expert"
    """What acts in the zone (:data:`Fallback`)."""
    stall: int = 0
    """Steps in a row with the same cost in every dimension (outside warm-up) after which the
    agent counts as stalled (a car standing still: its distances to the grass do not change)
    and the expert takes over for :attr:`stall_hold` steps, wherever the cost is; 0: off."""
    stall_hold: int = 0
    """Steps the expert acts after a stall (with :attr:`stall`)."""
    pace: float = 0.0
    """A speed (the car's, in the simulator's units: privileged, as the scripted expert is)
    below which the agent counts as falling behind: after :attr:`pace_steps` steps in a row
    below it (outside warm-up) the expert takes over for :attr:`pace_hold` steps, wherever the
    cost is (a car crawling after a corner, braking lightly without gas, long before it stands
    still); 0: off. Read by :func:`safe_bc.rollout.handover.pace_decision`."""
    pace_steps: int = 0
    """Steps in a row below :attr:`pace` that start the expert (with :attr:`pace`)."""
    pace_hold: int = 0
    """Steps the expert acts after the car fell below :attr:`pace` (with :attr:`pace`)."""

    def __post_init__(self) -> None:
        if not (isinstance(self.width, int | float) and math.isfinite(self.width)):
            raise ValueError(f"handover width must be a finite number, got {self.width!r}")
        if self.width < 0:
            raise ValueError(f"handover width must be >= 0, got {self.width}")
        for name in ("lookahead", "hold", "stall", "stall_hold", "pace_steps", "pace_hold"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"handover {name} must be an integer >= 0 steps, got {value!r}")
        if not (isinstance(self.pace, int | float) and math.isfinite(self.pace) and self.pace >= 0):
            raise ValueError(f"handover pace must be a finite speed >= 0, got {self.pace!r}")
        if self.pace and not (self.pace_steps and self.pace_hold):
            raise ValueError("a handover pace needs pace_steps and pace_hold > 0")
        object.__setattr__(self, "hold_on", tuple(str(d) for d in self.hold_on))
        pairs = tuple((str(d), float(w)) for d, w in dict(self.widths).items())
        for d, w in pairs:
            if not (math.isfinite(w) and w >= 0):
                raise ValueError(f"handover width of {d!r} must be a finite number >= 0, got {w}")
        object.__setattr__(self, "widths", pairs)
        if self.fallback not in FALLBACKS:
            raise ValueError(f"handover fallback must be one of {FALLBACKS}, got {self.fallback!r}")

    def __eq__(self, other: object) -> bool:
        """Equal when every setting is: the order ``widths`` lists its dimensions in does not
        count (a record read back from sorted JSON equals the config it was written from)."""
        if not isinstance(other, HandoverConfig):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict(), sort_keys=True))

    def width_per_dim(self, dims: tuple[str, ...]) -> tuple[float, ...]:
        """The zone's width in each of the task's safety dimensions ``dims``.

        >>> HandoverConfig(0.2, widths=(("fatigue", 0.15),)).width_per_dim(("hr", "fatigue"))
        (0.2, 0.15)
        """
        own = dict(self.widths)
        unknown = sorted(set(own) - set(dims))
        if unknown:
            raise ValueError(f"handover widths name unknown dimension(s) {unknown}: {list(dims)}")
        return tuple(own.get(d, float(self.width)) for d in dims)

    def label(self, unit: str = "") -> str:
        """A short description for tables and prints.

        >>> HandoverConfig(2.0, lookahead=6, hold=6, hold_on=("front",)).label(" px")
        'expert within 2 px of d_s 6 steps ahead, held 6 steps after front'
        """
        who = "the safest action" if self.fallback == "safest" else "expert"
        out = f"{who} within {self.width:g}{unit} of d_s"
        if self.widths:
            own = ", ".join(f"{d} {w:g}{unit}" for d, w in self.widths)
            out = f"{who} within w of d_s (w: {own}; else {self.width:g}{unit})"
        if self.lookahead:
            out += f" {self.lookahead} steps ahead"
        if self.hold:
            out += f", held {self.hold} steps"
            if self.hold_on:
                out += f" after {', '.join(self.hold_on)}"
        if self.fallback == "cap":
            out += ", capping the agent's action"
        if self.stall:
            out += f"; {self.stall_hold} steps after {self.stall} still steps"
        if self.pace:
            out += (
                f"; {self.pace_hold} steps after {self.pace_steps} steps below speed {self.pace:g}"
            )
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-able fields; ``widths``, ``fallback``, the stall restart and the pace rule only
        where set (a handover without them keeps the identity it always had)."""
        out = {**asdict(self), "hold_on": list(self.hold_on)}
        for key in ("widths", "fallback", "stall", "stall_hold", "pace", "pace_steps", "pace_hold"):
            out.pop(key)
        if self.widths:
            out["widths"] = dict(self.widths)
        if self.fallback != "expert":
            out["fallback"] = self.fallback
        if self.stall:
            out.update(stall=self.stall, stall_hold=self.stall_hold)
        if self.pace:
            out.update(pace=self.pace, pace_steps=self.pace_steps, pace_hold=self.pace_hold)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> HandoverConfig:
        """Inverse of :meth:`to_dict`."""
        return cls(
            width=float(data["width"]),
            lookahead=int(data.get("lookahead", 0)),
            hold=int(data.get("hold", 0)),
            hold_on=tuple(data.get("hold_on", ())),
            widths=tuple(dict(data.get("widths", {})).items()),
            fallback=data.get("fallback", "expert"),
            stall=int(data.get("stall", 0)),
            stall_hold=int(data.get("stall_hold", 0)),
            pace=float(data.get("pace", 0.0)),
            pace_steps=int(data.get("pace_steps", 0)),
            pace_hold=int(data.get("pace_hold", 0)),
        )
