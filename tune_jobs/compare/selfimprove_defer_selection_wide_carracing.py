"""The deferral width rule on a larger selection set: self-imitation with deferral to the expert
near the limit, 3 training seeds x 150 selection tracks (450 episodes per width).

Why: on ``selfimprove_defer_selection_carracing.py``'s 3 x 50 selection tracks the rule (the
smallest width with no episode beyond d_s) chose 2 px, and the fresh tracks then had 1 of
150 episodes beyond (``defer.md``): zero in 150 certifies a share below 2.0%, not zero in the
next 150. Three times as many selection episodes certify 0.66%. The widths: 4 px, the first
grid's other width, deferred 17% of the steps on the selection tracks (the goal allows 5%),
so this grid stays between: 2, 2.5 and 3 px.

The rule, fixed before this table was run: the smallest width of :data:`WIDTHS` with no
selection episode beyond d_s, else the largest; ``selfimprove_defer_wide_carracing.py``
then evaluates self-imitation at that width on fresh tracks (block 19). Only the
self-imitation agent (4 rounds, half-size pushes) gets the rows: the better of the two
improved agents with deferral on the first fresh tracks (1/150 against PPO-Lagrangian's
3/150).

Held-out seed block 18, which no other table uses. Shares ``selfimprove_carracing.py``'s runs
(``runs="compare"``: nothing is trained; the start and the agent are evaluated here too, on
these tracks). Run after it: ``safe-bc compare
tune_jobs/compare/selfimprove_defer_selection_wide_carracing.py``. Writes
``results/selfimprove/carracing/defer_selection_wide*``.
"""

from dataclasses import replace

from safe_bc.compare import sibling

WIDTHS = (2.0, 2.5, 3.0)
"""Deferral widths (px)."""
AGENT = "selfimitation"
"""The improved row that gets deferral."""

_compare = sibling(__file__, "selfimprove_carracing").COMPARISON
_first = sibling(__file__, "selfimprove_defer_selection_carracing")

COMPARISON = replace(
    _compare,
    name="defer_selection_wide",
    runs="compare",
    methods=(
        *(m for m in _compare.methods if m.name in ("expert", "imitation", AGENT)),
        *(_first.defer_row(AGENT, w) for w in WIDTHS),
    ),
    episodes=150,
    eval_seed=18,
    reference="expert",
    figures=(),
    title="Self-imitation with deferral to the expert near d_s: 3 x 150 selection tracks "
    "(CarRacing)",
    note="Selection tracks (block 18) for the width of issue 35's deferral. Paired rows: "
    "each agent against the expert on the same tracks. steps deferred: the mean share of an "
    "episode's steps on which the expert acted.",
)
