"""Deferral on the cost's trend on fresh tracks, at the (width, hold, lookahead) the
selection chose: the self-imitation agent of ``selfimprove_carracing.py`` beside the expert and
the start, paired with the expert.

The row comes from the committed
``results/selfimprove/carracing/defer_lookahead_selection.parquet``
(``selfimprove_defer_lookahead_selection_carracing.py``, 3 seeds x 150 selection tracks of
block 18) by the rule fixed there before it was run (``chosen`` of that file: among the rows with no
episode beyond d_s and a mean deferred share below 5%, the smallest share). No row met it
(zero crossings came only with 17% of steps deferred or more), so this file evaluates,
labelled as such, the row a relaxed rule picks, written after the selection table: the same
rule without the burden bound (:data:`RELAXED`). It measures whether zero crossings carry to
fresh tracks; it cannot meet the deferral goal (0 of 150 beyond d_s with under 5% of
steps deferred), whose burden bound it drops.

3 training seeds x 50 fresh tracks of held-out seed block 20, which no other table uses.
Shares the comparison's runs (``runs="compare"``). Run after the selection table is
committed: ``safe-bc compare tune_jobs/compare/selfimprove_defer_lookahead_carracing.py``.
Writes ``results/selfimprove/carracing/defer_lookahead*``.
"""

from pathlib import Path

import pandas as pd

from safe_bc.compare import sibling

_selection = sibling(__file__, "selfimprove_defer_lookahead_selection_carracing")
SELECTION_TABLE = Path(__file__).resolve().parents[2] / (
    "results/selfimprove/carracing/defer_lookahead_selection.parquet"
)
_table = pd.read_parquet(SELECTION_TABLE)
CHOSEN = _selection.chosen(_table, _selection.GRID)
"""The (width px, hold steps, lookahead steps) the rule chose on the selection tracks, or
``None`` (it is ``None``: no row deferred under 5% of steps with zero crossings)."""
RELAXED = _selection.chosen(_table, _selection.GRID, burden=1.0)
"""The row the rule picks without its burden bound (written after the selection table)."""
ROW = CHOSEN if CHOSEN is not None else RELAXED

COMPARISON = _selection.COMPARISON.with_deferral(
    ([] if ROW is None else [_selection.lookahead_row(*ROW)]),
    name="defer_lookahead",
    episodes=50,
    eval_seed=20,
    title="Self-imitation with deferral on the cost's trend: fresh tracks (CarRacing)",
    note="Fresh tracks (block 20); the deferral row was chosen on 3 x 150 selection tracks "
    "(defer_lookahead_selection.md)"
    + ("" if CHOSEN is not None else " by the rule without its 5% burden bound (none met it)")
    + ". Paired rows: each agent against the expert on the same "
    "tracks. steps deferred: the mean share of an episode's steps on which the expert acted.",
)
