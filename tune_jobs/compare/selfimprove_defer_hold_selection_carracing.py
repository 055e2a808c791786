"""Deferral whose handover lasts, on the 3 x 150 selection tracks of block 18.

Why: on these tracks (``selfimprove_defer_selection_wide_carracing.py``) deferral within 2,
2.5 and 3 px of d_s left 4, 2 and 3 of 450 episodes beyond d_s, on two tracks: the expert
took the car near the edge and handed it back as soon as the cost fell below the zone, and
the agent drove it back out. Here the expert keeps the car for ``hold`` steps after the last
step in the zone (``Method.defer_hold``, :class:`safe_bc.queries.defer.DeferringPolicy`).

Rows: the expert, the start, the self-imitation agent (as in the wide selection file) and
self-imitation with deferral at each (width, hold) of :data:`GRID`. The rule, fixed before
this table was run: among the rows with no selection episode beyond d_s and a mean deferred
share below 5% (the burden deferral may put on the expert), the smallest deferred share;
without one, no fresh-track row. No row met it, so no fresh-track file was run for this grid
(docs/queries.md).

Shares ``selfimprove_carracing.py``'s runs (``runs="compare"``; nothing is trained). Run:
``safe-bc compare tune_jobs/compare/selfimprove_defer_hold_selection_carracing.py``. Writes
``results/selfimprove/carracing/defer_hold_selection*``.
"""

from safe_bc.compare import Method, sibling

GRID = ((2.0, 10), (2.0, 25), (2.0, 50), (2.5, 25))
"""(width in px, hold in steps) of the deferral rows; 50 steps is one second of driving."""

_wide = sibling(__file__, "selfimprove_defer_selection_wide_carracing")
_agent = _wide.COMPARISON.method(_wide.AGENT)


def held_row(width: float, hold: int) -> Method:
    """The self-imitation agent with the expert within ``width`` px of d_s, held ``hold``
    steps after the last step in the zone."""
    return Method(
        f"{_wide.AGENT}+defer{width:g}hold{hold}",
        fallback_of=_wide.AGENT,
        defer_width=width,
        defer_hold=hold,
        label=f"{_agent.shown}, expert within {width:g} px of d_s, held {hold} steps",
    )


COMPARISON = _wide.COMPARISON.with_deferral(
    (held_row(w, h) for w, h in GRID),
    name="defer_hold_selection",
    title="Self-imitation with a held deferral to the expert: 3 x 150 selection tracks (CarRacing)",
    note="Selection tracks (block 18), the wide selection's. Paired rows: each agent against "
    "the expert on the same tracks. steps deferred: the mean share of an episode's steps on "
    "which the expert acted (held steps included).",
)
