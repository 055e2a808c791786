"""A cheaper handover on the cost's trend, on the 3 x 150 selection tracks of block 18.

Why: on ``selfimprove_defer_lookahead_selection_carracing.py``'s table the trend test reached
zero crossings in 450 selection episodes (6 steps ahead, held 10) and kept them on fresh tracks
(``defer_lookahead.md``: 0 of 150), but deferred 17% of the steps, where the goal allows 5%.
The hold made most of that burden (held 25 instead of 10 doubled it), so this grid shortens
the hold and narrows the zone at the same lookahead, and tries a shorter lookahead.

Rows: the expert, the start and the self-imitation agent (evaluated again here: the fresh-track
run of block 20 had replaced their stored evaluations in the shared runs folder; the same
episodes on one machine type) and self-imitation with deferral at each (width, hold, lookahead)
of :data:`GRID`. The rule, fixed before this table was run (the hold and lookahead files'):
among the rows with no selection episode beyond d_s and a mean deferred share below 5%, the
smallest share; without one, no fresh-track row.

Shares ``selfimprove_carracing.py``'s runs (``runs="compare"``). Run: ``safe-bc compare
tune_jobs/compare/selfimprove_defer_trend_selection_carracing.py``. Writes
``results/selfimprove/carracing/defer_trend_selection*``.
"""

from safe_bc.compare import sibling

GRID = ((2.0, 0, 6), (2.0, 5, 6), (1.0, 10, 6), (2.0, 10, 4))
"""(width px, hold steps, lookahead steps) of the deferral rows."""

_ahead = sibling(__file__, "selfimprove_defer_lookahead_selection_carracing")

COMPARISON = _ahead.COMPARISON.with_deferral(
    (_ahead.lookahead_row(*g) for g in GRID),
    name="defer_trend_selection",
    title="Self-imitation with a cheaper deferral on the cost's trend: 3 x 150 selection "
    "tracks (CarRacing)",
)
