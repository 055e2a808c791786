"""A handover that lasts through the corner, on the 3 x 150 selection tracks of
block 18.

Why: the cheaper trend handover (2 px, 6 steps ahead, no hold) crossed d_s in 1 of 150 fresh
episodes (``defer_trend.md``, block 21: seed 0, track 1075841861, one step 0.07 px beyond).
Replayed step by step, the front distance's trend handed the car to the expert for two steps
at a corner's entry (steps 734-735), the agent took it back as the front opened, left the
corner drifting to the right edge (right distance 8.6 px to 5.8 px in four steps), was handed
over again at 742 (8 px from the edge, nine steps before the crossing) and the expert, given
that state, crossed by 0.07 px at 751. The trigger was on time; the state was the agent's.
The 10-step hold had kept the expert through such exits (0 of 150 on block 20) but held
after every side-distance handover too (17% of steps). Here only a zone step of the front
distance (a corner ahead) starts the hold (``Method.defer_hold_on``); a side-distance
handover ends when the cost leaves the zone. On that track, this rule at holds 6-12 replays
without a crossing (a check on one seen episode, not a measurement; block 21 is no longer
fresh for this design, the fresh file uses block 22).

Rows: the expert, the start, the self-imitation agent (evaluated again here: the fresh-track
run of block 21 replaced their stored evaluations in the shared runs folder; the same episodes
on one machine type) and self-imitation with deferral at each (width, hold, lookahead) of
:data:`GRID`, the hold started by the front distance only. The rule, fixed before this table
was run (the earlier grids': ``chosen``): among the rows with no selection episode beyond d_s
and a mean deferred share below 5%, the smallest share; without one, no fresh-track row.

Shares ``selfimprove_carracing.py``'s runs (``runs="compare"``). Run: ``safe-bc compare
tune_jobs/compare/selfimprove_defer_corner_selection_carracing.py``. Writes
``results/selfimprove/carracing/defer_corner_selection*``.
"""

from dataclasses import replace

from safe_bc.compare import Method, sibling

GRID = ((2.0, 6, 6), (2.0, 10, 6), (2.0, 15, 6))
"""(width px, hold steps after a front-distance handover, lookahead steps) of the rows."""

HOLD_ON = ("front",)
"""The safety dimension whose zone test starts the hold."""

_trend = sibling(__file__, "selfimprove_defer_trend_selection_carracing")
_ahead = sibling(__file__, "selfimprove_defer_lookahead_selection_carracing")


def corner_row(width: float, hold: int, lookahead: int) -> Method:
    """The trend row of ``(width, hold, lookahead)`` with the hold started by the front
    distance only."""
    row = _ahead.lookahead_row(width, hold, lookahead)
    return replace(
        row,
        name=f"{row.name}front",
        handover=replace(row.handover, hold_on=HOLD_ON),
        label=f"{row.label} after the front distance",
    )


COMPARISON = _trend.COMPARISON.with_deferral(
    (corner_row(*g) for g in GRID),
    name="defer_corner_selection",
    title="Self-imitation with a handover that lasts through the corner: 3 x 150 selection "
    "tracks (CarRacing)",
    note="Selection tracks (block 18), the wide selection's. Paired rows: each agent against "
    "the expert on the same tracks. steps deferred: the mean share of an episode's steps on "
    "which the expert acted (held steps included); the hold starts only at a zone step of the "
    "front distance.",
)
