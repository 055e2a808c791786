"""Deferral over the improvements on CarRacing: the improved agents of ``selfimprove_carracing.py``
with deferral to the expert near the limit, on *selection* tracks that choose the width.

Rows: the expert, the start and both improved agents (PPO-Lagrangian + shield, self-imitation;
the same runs: :data:`COMPARISON` has the same rows and settings) and, for each improved agent
and each width ``w`` of :data:`WIDTHS`, the agent with the expert acting wherever the env's
measured cost is within ``w`` of d_s (``Method.defer_width``: deferral at use
time, :class:`safe_bc.queries.defer.DeferralSource`). The rule, fixed before the table: per
agent, the smallest width with no selection episode beyond d_s (the largest when none
reaches zero); ``selfimprove_defer_carracing.py`` then evaluates each agent at its width on
the fresh tracks of the comparison, paired with the expert there.

3 training seeds x 50 tracks of held-out seed block 17, which no other table uses.

Run after ``selfimprove_carracing.py``: ``safe-bc compare
tune_jobs/compare/selfimprove_defer_selection_carracing.py``. It shares that comparison's runs
folder (``runs="compare"``: nothing is trained again; an improvement run's folder names its
start's path, so a copy elsewhere would retrain), so its evaluations on these tracks replace
the stored ones of the shared rows, and the next run on the fresh tracks evaluates those rows
again (the same episodes on one machine type; a few minutes). Writes
``results/selfimprove/carracing/defer_selection*``.
"""

from dataclasses import replace

from safe_bc.compare import Method, sibling

WIDTHS = (2.0, 4.0)
"""Deferral widths (px): the car's queries measurement chose 4 px for plain BC and 2 px over
the critical-zone queries' agent (``results/queries/carracing``)."""
AGENTS = ("ppo_lagrangian", "selfimitation")
"""The improved rows that get deferral."""

_compare = sibling(__file__, "selfimprove_carracing").COMPARISON


def defer_row(agent: str, width: float) -> Method:
    """``agent`` with the expert acting within ``width`` px of d_s."""
    label = f"{_compare.method(agent).shown}, expert within {width:g} px of d_s"
    return Method(f"{agent}+defer{width:g}", fallback_of=agent, defer_width=width, label=label)


COMPARISON = replace(
    _compare,
    name="defer_selection",
    runs="compare",
    methods=(
        *_compare.methods,
        *(defer_row(agent, w) for agent in AGENTS for w in WIDTHS),
    ),
    eval_seed=17,
    reference="expert",
    figures=(),
    title="Improved agents with deferral to the expert near d_s: selection tracks (CarRacing)",
    note="Paired rows: each agent against the expert on the same selection tracks. steps "
    "deferred: the mean share of an episode's steps on which the expert acted.",
)
