"""The improved agents with deferral on CarRacing's fresh tracks: each improved agent of
``selfimprove_carracing.py`` with deferral to the expert at the width its selection table
chose, beside the expert, the start and the agents alone, paired with the expert.

The widths come from the committed ``results/selfimprove/carracing/defer_selection.parquet``
(``selfimprove_defer_selection_carracing.py``, selection tracks of block 17) by the rule fixed
there before it was run (:func:`chosen_width`: the smallest width with no selection episode
beyond d_s, else the largest tried). Runs and stored evaluations are the comparison's own
(``runs="compare"``, the same fresh tracks of block 14): only the deferral rows are evaluated.

Run after both: ``safe-bc compare tune_jobs/compare/selfimprove_defer_carracing.py``.
Writes ``results/selfimprove/carracing/defer*`` (``defer_selection*`` is the selection's).
"""

from dataclasses import replace
from pathlib import Path

import pandas as pd

from safe_bc.compare import sibling

_selection = sibling(__file__, "selfimprove_defer_selection_carracing")
SELECTION_TABLE = Path(__file__).resolve().parents[2] / (
    "results/selfimprove/carracing/defer_selection.parquet"
)


def chosen_width(table: pd.DataFrame, agent: str, widths: tuple[float, ...]) -> float:
    """The smallest of ``widths`` whose deferral row of ``agent`` had no selection episode
    beyond d_s (``episodes_with_violation``), else the largest."""
    beyond = table.set_index("method")["episodes_with_violation"]
    for w in sorted(widths):
        if int(beyond[_selection.defer_row(agent, w).name]) == 0:
            return w
    return max(widths)


_table = pd.read_parquet(SELECTION_TABLE)
WIDTH = {a: chosen_width(_table, a, _selection.WIDTHS) for a in _selection.AGENTS}
"""Each improved agent's deferral width (px), chosen on the selection tracks."""

COMPARISON = replace(
    sibling(__file__, "selfimprove_carracing").COMPARISON,
    name="defer",
    runs="compare",
    methods=(
        *sibling(__file__, "selfimprove_carracing").COMPARISON.methods,
        *(_selection.defer_row(a, WIDTH[a]) for a in _selection.AGENTS),
    ),
    reference="expert",
    figures=(),
    title="Improved agents with deferral to the expert near d_s: fresh tracks (CarRacing)",
    note="Paired rows: each agent against the expert on the same fresh tracks. steps "
    "deferred: the mean share of an episode's steps on which the expert acted. Widths "
    "chosen on the selection tracks (defer_selection.md).",
)
