"""The handover that lasts through the corner on fresh tracks, at the (width, hold,
lookahead) the selection chose: the self-imitation agent of ``selfimprove_carracing.py``
beside the expert and the start, paired with the expert.

The row comes from the committed
``results/selfimprove/carracing/defer_corner_selection.parquet``
(``selfimprove_defer_corner_selection_carracing.py``, 3 seeds x 150 selection tracks of block
18) by the rule fixed there before it was run (``chosen`` of
``selfimprove_defer_lookahead_selection_carracing.py``: among the rows with no episode beyond
d_s and a mean deferred share below 5%, the smallest share; none: no row).

3 training seeds x 50 fresh tracks of held-out seed block 22, which no other table uses
(block 21, where the trend handover crossed once, motivated this design and is not fresh for
it). Shares the comparison's runs (``runs="compare"``). Run after the selection table is
committed: ``safe-bc compare tune_jobs/compare/selfimprove_defer_corner_carracing.py``.
Writes ``results/selfimprove/carracing/defer_corner*``.
"""

from safe_bc.compare import sibling

_ahead = sibling(__file__, "selfimprove_defer_lookahead_selection_carracing")
_selection = sibling(__file__, "selfimprove_defer_corner_selection_carracing")

COMPARISON = _ahead.fresh(
    _selection,
    "defer_corner_selection",
    _selection.corner_row,
    name="defer_corner",
    eval_seed=22,
    title="Self-imitation with a handover that lasts through the corner: fresh tracks (CarRacing)",
    note="Fresh tracks (block 22); the deferral row was chosen on 3 x 150 selection tracks "
    "(defer_corner_selection.md). Paired rows: each agent against the expert on the same "
    "tracks. steps deferred: the mean share of an episode's steps on which the expert acted; "
    "the hold starts only at a zone step of the front distance.",
)
