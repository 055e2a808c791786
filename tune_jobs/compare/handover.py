"""Handing CarRacing's improved agents to the expert near d_s: deferral designs, each chosen on
selection tracks by a rule fixed before its table ran, then run on fresh tracks.

Every table has the expert, the safety-imitation start and improved agents of the
self-imitation comparison (``selfimprove.py``'s ``compare_carracing``: its runs folder
``compare``, nothing trained again), plus handover rows: the agent with the expert acting
where the env's measured cost is within ``width`` px of d_s (:class:`safe_bc.handover.
HandoverConfig`: optionally extrapolated ``lookahead`` steps along its trend, and held
``hold`` steps after a zone step, of the ``hold_on`` dimensions only). Paired with the
expert; ``steps deferred`` is the mean share of an episode's steps on which the expert acted
(the burden on the expert).

Selection tables (3 training seeds; block 17: 50 tracks, block 18: 150) and the fresh table
each one's rule feeds (50 tracks each, a block no other table uses):

* ``defer_selection`` (block 17; both improved agents at 2 and 4 px) -> ``defer`` (block 14,
  the self-imitation comparison's own fresh tracks): per agent the smallest width with no
  selection episode beyond d_s, else the largest (rule ``smallest_safe_width``);
* ``defer_selection_wide`` (block 18; self-imitation at 2, 2.5, 3 px) -> ``defer_wide``
  (block 19), the same rule;
* ``defer_hold_selection`` (block 18; held handovers): rule ``least_deferred`` (among the rows
  with no selection episode beyond d_s and a deferred share below 5%, the smallest share);
  no row met it, so it has no fresh table;
* ``defer_lookahead_selection`` (block 18; the cost's trend, held) -> ``defer_lookahead``
  (block 20): ``least_deferred`` at 5%, else at 100% (the bound dropped; the note says so);
* ``defer_trend_selection`` (block 18; shorter holds, narrower zones) -> ``defer_trend``
  (block 21): ``least_deferred`` at 5%;
* ``defer_corner_selection`` (block 18; the hold started by the front distance only, a corner
  ahead) -> ``defer_corner`` (block 22) and ``defer_corner_replication`` (block 23, nothing
  changed but the tracks): ``least_deferred`` at 5%.

A fresh table's rows are chosen when it runs, from its selection's committed table
(``results/selfimprove/carracing/<selection>.parquet``). Run: ``safe-bc compare
tune_jobs/compare/handover.py --name NAME``. Writes ``results/selfimprove/carracing/<name>*``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare.protocol import Fresh, Rule
from safe_bc.compare.spec import Agent, Comparison, Expert, FromStart, Handover
from safe_bc.handover import HandoverConfig
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.methods.selfimprove.config import SelfImproveConfig
from safe_bc.methods.selfimprove.sizing import ppo_at_budget, rollout_episodes, validation_budget
from safe_bc.selection import SelectionConfig

SELF = SelfImproveConfig()
"""The self-imitation row of the comparison (the package's defaults)."""
PPO = ppo_at_budget(
    ImproveConfig(episodes_per_iter=4, n_envs=4, cost_margin=1.0, checkpoint_every=1,
                  shield=True, lagrangian=True),
    rollout_episodes(SELF, "carracing"), 4, validation_budget(SELF, "carracing"), 4,
)  # fmt: skip
"""The PPO-Lagrangian row of the comparison (self-imitation's env-step budget)."""
LABELS = {
    "ppo_lagrangian": "PPO-Lagrangian + shield",
    "selfimitation": "self-imitation (4 rounds, half-size pushes)",
}
"""The improved agents and how tables name them."""
COMPARE = Comparison(
    name="compare",
    methods=(
        Expert("expert", label="expert (scripted, privileged)"),
        Agent(
            "imitation",
            SelectionConfig(eps=2.0, alpha=0.1),
            label="safety-imitation start (alpha 0.1)",
        ),
        FromStart("ppo_lagrangian", "imitation", PPO, label=LABELS["ppo_lagrangian"]),
        FromStart("selfimitation", "imitation", SELF, label=LABELS["selfimitation"]),
    ),
    task="carracing",
    out=Path("results/selfimprove/carracing"),
    train_seeds=(0, 1, 2),
    episodes=50,
    eval_seed=14,
    paired_metrics=("reward", "violation_steps"),
    totals=("any_violation",),
    per_seed=True,
)
"""The self-imitation comparison's rows and settings, which every table here starts from."""


def row(
    agent: str,
    width: float,
    hold: int | None = None,
    lookahead: int | None = None,
    front: bool = False,
) -> Handover:
    """``agent`` with the expert within ``width`` px of d_s (``lookahead`` steps ahead), held
    ``hold`` steps (after a zone step of the front distance only, with ``front``); the name
    and label spell out the ``hold`` and ``lookahead`` given, zero included."""
    name = f"{agent}+defer{width:g}" + ("" if hold is None else f"hold{hold}")
    name += "" if lookahead is None else f"ahead{lookahead}"
    label = f"{LABELS[agent]}, expert within {width:g} px of d_s"
    label += "" if lookahead is None else f" {lookahead} steps ahead"
    label += "" if hold is None else f", held {hold} steps"
    if front:
        name, label = f"{name}front", f"{label} after the front distance"
    config = HandoverConfig(
        width, lookahead=lookahead or 0, hold=hold or 0, hold_on=("front",) * front
    )
    return Handover(name, agent, config, label=label)  # fmt: skip


SAFEST = (Rule("smallest_safe_width"),)
"""Per agent, the smallest width with no selection episode beyond d_s, else the largest."""
CHEAPEST = (Rule("least_deferred", {"burden": 0.05}),)
"""The smallest deferred share among the rows with no selection episode beyond d_s and a share
below 5%; none: no handover row."""
PAIRED = "Paired rows: each agent against the expert on the same"
DEFERRED = "steps deferred: the mean share of an episode's steps on which the expert acted"
SELECTION = replace(
    COMPARE,
    name="defer_selection",
    runs="compare",
    methods=(*COMPARE.methods, *(row(a, w) for a in LABELS for w in (2.0, 4.0))),
    eval_seed=17,
    reference="expert",
    title="Improved agents with deferral to the expert near d_s: selection tracks (CarRacing)",
    note=f"{PAIRED} selection tracks. {DEFERRED}.",
)
WIDE = replace(
    SELECTION,
    name="defer_selection_wide",
    methods=(*COMPARE.methods[:2], COMPARE.methods[3],
             *(row("selfimitation", w) for w in (2.0, 2.5, 3.0))),
    episodes=150,
    eval_seed=18,
    title="Self-imitation with deferral to the expert near d_s: 3 x 150 selection tracks "
    "(CarRacing)",
    note=f"Selection tracks (block 18) for the width of the wide-block deferral. {PAIRED} "
    f"tracks. {DEFERRED}.",
)  # fmt: skip
HELD = f"Selection tracks (block 18), the wide selection's. {PAIRED} tracks. {DEFERRED}"
HOLD = WIDE.with_deferral(
    (row("selfimitation", w, h) for w, h in ((2.0, 10), (2.0, 25), (2.0, 50), (2.5, 25))),
    name="defer_hold_selection",
    title="Self-imitation with a held deferral to the expert: 3 x 150 selection tracks (CarRacing)",
    note=f"{HELD} (held steps included).",
)
LOOKAHEAD = HOLD.with_deferral(
    (
        row("selfimitation", w, h, a)
        for w, h, a in ((2.0, 25, 3), (2.0, 25, 6), (2.0, 10, 6), (2.0, 25, 10))
    ),
    name="defer_lookahead_selection",
    title="Self-imitation with deferral on the cost's trend: 3 x 150 selection tracks (CarRacing)",
)
TREND = LOOKAHEAD.with_deferral(
    (
        row("selfimitation", w, h, a)
        for w, h, a in ((2.0, 0, 6), (2.0, 5, 6), (1.0, 10, 6), (2.0, 10, 4))
    ),
    name="defer_trend_selection",
    title="Self-imitation with a cheaper deferral on the cost's trend: 3 x 150 selection "
    "tracks (CarRacing)",
)
CORNER = TREND.with_deferral(
    (row("selfimitation", 2.0, h, 6, front=True) for h in (6, 10, 15)),
    name="defer_corner_selection",
    title="Self-imitation with a handover that lasts through the corner: 3 x 150 selection "
    "tracks (CarRacing)",
    note=f"{HELD} (held steps included); the hold starts only at a zone step of the front "
    "distance.",
)
CORNER_NOTE = (
    "the deferral row was chosen on 3 x 150 selection tracks (defer_corner_selection.md). "
    f"{PAIRED} tracks. {DEFERRED}; the hold starts only at a zone step of the front distance."
)
CORNER_TITLE = "Self-imitation with a handover that lasts through the corner"

COMPARISONS = (
    SELECTION,
    Fresh(
        "defer", "defer_selection", SAFEST, eval_seed=14,
        title="Improved agents with deferral to the expert near d_s: fresh tracks (CarRacing)",
        note=f"{PAIRED} fresh tracks. {DEFERRED}. Widths chosen on the selection tracks "
        "(defer_selection.md).",
    ),
    WIDE,
    Fresh(
        "defer_wide", "defer_selection_wide", SAFEST, eval_seed=19, episodes=50,
        title="Self-imitation with deferral to the expert near d_s: fresh tracks (CarRacing)",
        note="Fresh tracks (block 19); the width was chosen on 3 x 150 selection tracks "
        f"(defer_selection_wide.md). {PAIRED} tracks. {DEFERRED}.",
    ),
    HOLD,
    LOOKAHEAD,
    Fresh(
        "defer_lookahead", "defer_lookahead_selection",
        (*CHEAPEST, Rule("least_deferred", {"burden": 1.0},
                         note=" by the rule without its 5% burden bound (none met it)")),
        eval_seed=20, episodes=50,
        title="Self-imitation with deferral on the cost's trend: fresh tracks (CarRacing)",
        note="Fresh tracks (block 20); the deferral row was chosen on 3 x 150 selection tracks "
        f"(defer_lookahead_selection.md){{rule}}. {PAIRED} tracks. {DEFERRED}.",
    ),
    TREND,
    Fresh(
        "defer_trend", "defer_trend_selection", CHEAPEST, eval_seed=21, episodes=50,
        title="Self-imitation with a cheaper deferral on the cost's trend: fresh tracks "
        "(CarRacing)",
        note="Fresh tracks (block 21); the deferral row was chosen on 3 x 150 selection tracks "
        f"(defer_trend_selection.md). {PAIRED} tracks. {DEFERRED}.",
    ),
    CORNER,
    Fresh(
        "defer_corner", "defer_corner_selection", CHEAPEST, eval_seed=22, episodes=50,
        title=f"{CORNER_TITLE}: fresh tracks (CarRacing)",
        note=f"Fresh tracks (block 22); {CORNER_NOTE}",
    ),
    Fresh(
        "defer_corner_replication", "defer_corner_selection", CHEAPEST, eval_seed=23, episodes=50,
        title=f"{CORNER_TITLE}: a second fresh block (CarRacing)",
        note=f"Fresh tracks (block 23, a replication of block 22's table); {CORNER_NOTE}",
    ),
)  # fmt: skip
