"""Deferral on fresh tracks, at the width the larger selection set chose: the
self-imitation agent of ``selfimprove_carracing.py`` with the expert acting within the chosen
width of d_s, beside the expert, the start and the agent alone, paired with the expert.

The width comes from the committed
``results/selfimprove/carracing/defer_selection_wide.parquet``
(``selfimprove_defer_selection_wide_carracing.py``: 3 seeds x 150 selection tracks of block
18) by the rule fixed there before it was run (the smallest width with no selection episode
beyond d_s, else the largest: ``selfimprove_defer_carracing.chosen_width``).

3 training seeds x 50 fresh tracks of held-out seed block 19, which no other table uses (the
first fresh tracks, block 14, were seen after the first width rule: ``defer.md``). Shares the
comparison's runs (``runs="compare"``). Run after the selection table is committed:
``safe-bc compare tune_jobs/compare/selfimprove_defer_wide_carracing.py``. Writes
``results/selfimprove/carracing/defer_wide*``.
"""

from pathlib import Path

import pandas as pd

from safe_bc.compare import sibling

_selection = sibling(__file__, "selfimprove_defer_selection_wide_carracing")
_first = sibling(__file__, "selfimprove_defer_selection_carracing")
SELECTION_TABLE = Path(__file__).resolve().parents[2] / (
    "results/selfimprove/carracing/defer_selection_wide.parquet"
)
WIDTH = sibling(__file__, "selfimprove_defer_carracing").chosen_width(
    pd.read_parquet(SELECTION_TABLE), _selection.AGENT, _selection.WIDTHS
)
"""The self-imitation agent's deferral width (px), chosen on the 450 selection episodes."""

COMPARISON = _selection.COMPARISON.with_deferral(
    [_first.defer_row(_selection.AGENT, WIDTH)],
    name="defer_wide",
    episodes=50,
    eval_seed=19,
    title="Self-imitation with deferral to the expert near d_s: fresh tracks (CarRacing)",
    note="Fresh tracks (block 19); the width was chosen on 3 x 150 selection tracks "
    "(defer_selection_wide.md). Paired rows: each agent against the expert on the same "
    "tracks. steps deferred: the mean share of an episode's steps on which the expert acted.",
)
