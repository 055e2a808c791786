"""The critical-zone handover's settings (stdlib only: study files, task records and the CLI read
it without torch or Ray).

The handover turns an agent into a recommender that never acts where the expert's own limit is
close: the expert acts wherever the measured cost, extrapolated ``lookahead`` steps along its
last change, is within ``width`` of ``d_s`` in some dimension, and for ``hold`` more steps
after a zone step of the ``hold_on`` dimensions. :class:`safe_bc.queries.defer.DeferringPolicy`
carries it out.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any


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

    def __post_init__(self) -> None:
        if not (isinstance(self.width, int | float) and math.isfinite(self.width)):
            raise ValueError(f"handover width must be a finite number, got {self.width!r}")
        if self.width < 0:
            raise ValueError(f"handover width must be >= 0, got {self.width}")
        for name in ("lookahead", "hold"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"handover {name} must be an integer >= 0 steps, got {value!r}")
        object.__setattr__(self, "hold_on", tuple(str(d) for d in self.hold_on))

    def label(self, unit: str = "") -> str:
        """A short description for tables and prints.

        >>> HandoverConfig(2.0, lookahead=6, hold=6, hold_on=("front",)).label(" px")
        'expert within 2 px of d_s 6 steps ahead, held 6 steps after front'
        """
        out = f"expert within {self.width:g}{unit} of d_s"
        if self.lookahead:
            out += f" {self.lookahead} steps ahead"
        if self.hold:
            out += f", held {self.hold} steps"
            if self.hold_on:
                out += f" after {', '.join(self.hold_on)}"
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-able fields."""
        return {**asdict(self), "hold_on": list(self.hold_on)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> HandoverConfig:
        """Inverse of :meth:`to_dict`."""
        return cls(
            width=float(data["width"]),
            lookahead=int(data.get("lookahead", 0)),
            hold=int(data.get("hold", 0)),
            hold_on=tuple(data.get("hold_on", ())),
        )
