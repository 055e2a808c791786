"""Self-imitation against PPO-Lagrangian, the start and the expert; its safety choices.

Fresh tracks, equal env-step budgets:

* ``compare_carracing`` (3 training seeds x 50 held-out tracks of block 14) and
  ``compare_rehab`` (3 x 200 patients of block 15): the expert; the safety-imitation start
  (the paired reference; CarRacing: BC with alpha 0.1, eps 2 px; rehab: alpha 0.5, eps 0.05);
  PPO-Lagrangian + shield and self-imitation (the package's defaults, which the selection
  tables chose), each from every seed's start. Self-imitation rolls out ``rounds x
  tracks_per_round x (1 + pushes)`` training episodes
  (:func:`safe_bc.methods.selfimprove.sizing.rollout_episodes`: 576 on CarRacing, episodes of at
  most 1000 steps; 240 on rehab, episodes of 30 sessions); the PPO row runs as many, and as many
  validation episodes (:func:`~safe_bc.methods.selfimprove.sizing.ppo_at_budget`). Both run in the
  driver process, rollouts in-process, so wall times compare. The table records each run's
  env steps (training rollouts; validation) and minutes, ``compare_history.parquet`` the
  learning curves.
* ``compare_vs_expert_carracing``, ``compare_vs_expert_rehab``: the same rows, runs and stored
  evaluations paired against the expert (standing in for every training seed); nothing runs
  again.

Selection tracks, which chose the defaults (so the fresh tables report other blocks):

* ``selection_carracing`` (3 x 50 tracks of block 13) and ``selection_rehab`` (3 x 200 patients
  of block 16): self-imitation with the defaults of the time (:data:`CAR_DEFAULT`,
  :data:`REHAB_DEFAULT`: 2 rounds, kept rows in the rest pool) and one row per safety choice,
  each changing one field: a margin inside d_s, kept segments, kept rows in T_eps, no back-off
  in the critical zone, T_eps half of each retraining batch, a 5% bound of the keep rule (with
  64 validation tracks), 4 rounds, 4 rounds of half-size pushes.
* ``rounds_carracing``: the defaults, 4 rounds, 4 rounds of half-size pushes on CarRacing
  (``selection_carracing``'s runs: a round never depends on how many follow, so the defaults'
  first two rounds are copied). The rule that turns these three tables into defaults is their
  report step (:data:`CHOICE`, :mod:`safe_bc.methods.selfimprove.choice`): the runner writes
  ``choice.md`` (``rounds_choice.md``) beside the table; ``--report-only`` reruns only it.

Beyond the expert, planned before it runs (docs/improvement.md):

* ``beyond_selection`` (3 x 50 tracks of block 24): from the same starts, four self-imitation
  candidates, each evaluated alone and with the task's corner handover (``TaskSpec.handover``):
  A the defaults; B A keeping only pushed runs that beat the expert's run on the same track;
  C B exploring under the handover with the loop's full-size pushes; D C keeping at most the
  best 2 pushed runs per track.
* ``beyond`` (block 25) and ``beyond_replication`` (block 26, nothing changed but the tracks):
  the handover row the rule picks on the selection table (no episode beyond d_s, under 5% of
  steps deferred, the highest lower bound of the paired reward interval against the expert;
  ties: fewer env steps), beside every candidate alone, the start and the expert, paired with
  the expert. Cost: 12 self-imitation runs (26-37 min each on 2 cores in one process).
* ``beyond_stall_selection`` (3 x 50 tracks of block 88), ``beyond_stall`` (89),
  ``beyond_stall_replication`` (90): the car's second design, written after the first's pick
  missed on block 26, where every agent stopped on one track: D's agents with the corner
  handover and the expert restarting a car that stood still 20 steps (for 50 or 100 steps).
* ``beyond_pace_selection`` (3 x 50 tracks of block 94), ``beyond_pace`` (95),
  ``beyond_pace_replication`` (96): the car's third design, written after the second's pick
  was level with the expert on blocks 89 and 90, where on one long track a block the agent
  crawled after a corner (light brake, no gas) and lost 130-190 points to the time limit:
  the second design's pick with the expert driving 50 steps where the car's speed stayed
  below 30 (or 20) for 10 steps (``HandoverConfig.pace``, privileged like the expert).
  ``beyond_pace_deferral`` (block 95): a diagnostic after them, the second design's pick on
  block 95, to read the pace rule's share of the deferred steps.
* ``beyond_lean_selection`` (3 x 50 tracks of block 94 again, the runs folder shared),
  ``beyond_lean`` (97), ``beyond_lean_replication`` (98): the car's fourth design, written after
  the third's pick deferred 5.3% of steps on block 95: the third pick with a smaller corner zone
  (hold 3, lookahead 3 or width 1.5 px).
* ``beyond_selection_rehab`` (3 x 200 patients of block 63), ``beyond_rehab`` (block 64),
  ``beyond_replication_rehab`` (block 65): the same design in the clinic (A the clinic's
  defaults; B kept only above the guideline's run; C B under the clinic's handover; D C with
  the best 2 pushed runs per patient), the rule's deferral bound 10%.
* ``beyond_selection_rehab_lagrangian`` (3 x 200 patients of block 70),
  ``beyond_rehab_lagrangian`` (block 71), ``beyond_replication_rehab_lagrangian`` (block 72):
  the clinic's second design, written after the first put every self-imitation candidate
  below the guideline: the two PPO-Lagrangian improvers that beat the guideline in the
  improvement table (Lagrangian only; shield + Lagrangian), each alone and under each of the
  clinic's handovers (the task's: the safest action in the zone; the cap), the same rule
  (no selection programme beyond d_s, under 10% of sessions deferred, the highest paired
  lower bound). Writes ``results/selfimprove/rehab_lagrangian/``.
* ``beyond_narrow_selection_rehab_lagrangian`` (block 73), ``beyond_narrow_rehab_lagrangian``
  (74), ``beyond_narrow_replication_rehab_lagrangian`` (75): the third, written after the
  second's cap rows stayed inside d_s with the gain but acted on 13.5-17.9% of sessions: the
  same agents (its runs) under the cap at half and a quarter of its widths, the same rule.
* ``beyond_mid_selection_rehab_lagrangian`` (block 76), ``beyond_mid_rehab_lagrangian`` (77),
  ``beyond_mid_replication_rehab_lagrangian`` (78): the fourth, written after the third's
  narrow caps acted on 0.3-1.6% of sessions but let 2-5 of 600 programmes beyond d_s: the cap
  at 0.75 and 0.6 of its widths.
* ``beyond_early_selection_rehab_lagrangian`` (block 82), ``beyond_early_rehab_lagrangian`` (83),
  ``beyond_early_replication_rehab_lagrangian`` (84): the fifth, written after the fourth's
  caps let one selection programme beyond d_s, the same patient for every row, after acting
  on 40-70% of its sessions: the 0.6 cap acting a session ahead, or held 2 sessions.

Run: ``safe-bc compare tune_jobs/compare/selfimprove.py --name NAME`` (resumes per method,
seed and round; ``--cell METHOD:SEED --workers 0`` runs one cell in its own process). Writes
``results/selfimprove/<task>/<name>*``.
"""

from dataclasses import replace
from pathlib import Path
from typing import Any

from safe_bc.compare.protocol import Fresh, Rule
from safe_bc.compare.spec import Agent, Comparison, Expert, FromStart, Handover, Report, Row
from safe_bc.handover import HandoverConfig
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.methods.selfimprove.config import LOOP_PUSHES, SelfImproveConfig
from safe_bc.methods.selfimprove.sizing import (
    half,
    ppo_at_budget,
    rollout_episodes,
    validation_budget,
)
from safe_bc.selection import SelectionConfig
from safe_bc.tasks import task_defaults

SELF = SelfImproveConfig()
"""The fresh tables' self-imitation: the package's defaults (CarRacing: 4 rounds of half-size
pushes; rehab: 2 rounds, kept rows in T_eps)."""
CAR_EPISODES = rollout_episodes(SELF, "carracing")
"""CarRacing's shared training budget in episodes (576 with the defaults)."""
REHAB_EPISODES = rollout_episodes(SELF, "rehab")
"""Rehab's shared training budget in episodes (240 with the defaults)."""
CAR_PPO = ppo_at_budget(
    ImproveConfig(episodes_per_iter=4, n_envs=4, cost_margin=1.0, checkpoint_every=1,
                  shield=True, lagrangian=True),
    CAR_EPISODES, 4, validation_budget(SELF, "carracing"), 4,
)  # fmt: skip
"""PPO-Lagrangian + shield at CarRacing's budget: 4-episode iterations (the improvement
table's sizing for pixels, cost margin 1 px), 4 validations."""
REHAB_PPO = ppo_at_budget(
    ImproveConfig(eps=0.1, shield=True, lagrangian=True),
    REHAB_EPISODES, 16, validation_budget(SELF, "rehab"), 3,
)  # fmt: skip
"""PPO-Lagrangian + shield at rehab's budget: the improvement table's settings (shield zone
0.1), 16-patient iterations, 3 validations."""
CAR_START = SelectionConfig(eps=2.0, alpha=0.1)
"""CarRacing's safety-imitation start (as in the improvement table)."""
REHAB_START = SelectionConfig(eps=0.05, alpha=0.5)
"""Rehab's safety-imitation start (as in the improvement table)."""
CAR_DEFAULT = SelfImproveConfig(
    rounds=2, pushes=LOOP_PUSHES["carracing"], kept_in="rest", workers=8
)
"""CarRacing's defaults when its selection table was made (rollouts on 8 Ray actors; results
do not depend on it)."""
REHAB_DEFAULT = SelfImproveConfig(rounds=2, pushes=LOOP_PUSHES["rehab"], kept_in="rest")
"""Rehab's defaults when its selection table was made."""
MARGIN = REHAB_START.eps / 2
"""Rehab's margin row: half the selection's eps inside d_s (as 1 px is half CarRacing's 2)."""

CAR_CHOICES = {  # name: (label, config)
    "defaults": ("self-imitation, defaults", CAR_DEFAULT),
    "margin1px": ("margin 1 px inside d_s", replace(CAR_DEFAULT, margin=1.0)),
    "segment": ("kept segments (50 steps)", replace(CAR_DEFAULT, keep_unit="segment")),
    "critical": ("kept rows in T_eps", replace(CAR_DEFAULT, kept_in="critical")),
    "no_backoff": ("no back-off in the critical zone", replace(CAR_DEFAULT, backoff=False)),
    "alpha05": ("T_eps half of each retraining batch", replace(CAR_DEFAULT, alpha=0.5)),
    "bound05": ("keep rule bound 5% (64 validation tracks)",
                replace(CAR_DEFAULT, beyond_limit=0.05, validation_episodes=64)),
}  # fmt: skip
CAR_ROUNDS = {
    "defaults": CAR_CHOICES["defaults"],
    "rounds4": ("4 rounds", replace(CAR_DEFAULT, rounds=4)),
    "rounds4_small": ("4 rounds, half-size pushes",
                      replace(CAR_DEFAULT, rounds=4,
                              pushes=tuple(half(s) for s in LOOP_PUSHES["carracing"]))),
}  # fmt: skip
REHAB_CHOICES = {
    "defaults": ("self-imitation, defaults", REHAB_DEFAULT),
    "margin": (f"margin {MARGIN:g} inside d_s", replace(REHAB_DEFAULT, margin=MARGIN)),
    "segment": ("kept segments (10 sessions)",
                replace(REHAB_DEFAULT, keep_unit="segment", segment_steps=10)),
    "critical": ("kept rows in T_eps", replace(REHAB_DEFAULT, kept_in="critical")),
    "no_backoff": ("no back-off in the critical zone", replace(REHAB_DEFAULT, backoff=False)),
    "rounds4": ("4 rounds", replace(REHAB_DEFAULT, rounds=4)),
    "rounds4_small": ("4 rounds, half-size pushes",
                      replace(REHAB_DEFAULT, rounds=4,
                              pushes=tuple(half(s) for s in LOOP_PUSHES["rehab"]))),
}  # fmt: skip


def car_rows(choices: dict[str, tuple[str, SelfImproveConfig]]) -> tuple[Row, ...]:
    """The expert, the CarRacing start and one self-imitation row per choice."""
    return (
        Expert("expert", label="expert (scripted, privileged)"),
        Agent("imitation", CAR_START, label="safety-imitation start (alpha 0.1)"),
        *(FromStart(n, "imitation", c, label=label) for n, (label, c) in choices.items()),
    )


CHOICE = "safe_bc.methods.selfimprove.choice:markdown"
"""The selection tables' report step: the setting each table supports, by the rule fixed
before the CarRacing table existed."""

CAR_PAIRED = "Paired rows: each agent against its own seed's start on the same"
"""The CarRacing notes' shared sentence (followed by the tracks' kind)."""
CAR = Comparison(
    name="compare",
    methods=(
        *car_rows({}),
        FromStart("ppo_lagrangian", "imitation", CAR_PPO, label="PPO-Lagrangian + shield"),
        FromStart(
            "selfimitation", "imitation", SELF, label="self-imitation (4 rounds, half-size pushes)"
        ),
    ),
    task="carracing",
    out=Path("results/selfimprove/carracing"),
    train_seeds=(0, 1, 2),
    episodes=50,
    eval_seed=14,
    reference="imitation",
    paired_metrics=("reward", "violation_steps"),
    totals=("any_violation",),
    per_seed=True,
    figures=(("learning_curves", "compare_learning_curves.png"),),
    title="Self-imitation vs PPO-Lagrangian on CarRacing, equal env-step budgets",
    note=f"Both improvements from the same starts with at most {CAR_EPISODES * 1000:,} "
    f"training env steps per run. {CAR_PAIRED} fresh tracks. env steps / run: training "
    "rollouts; validation env steps / run: the episodes that pick (PPO) or accept "
    "(self-imitation) the final agent.",
)
CAR_SELECTION = replace(
    CAR,
    name="selection",
    methods=car_rows(CAR_CHOICES),
    eval_seed=13,
    totals=(),
    figures=(("learning_curves", "selection_learning_curves.png"),),
    report=Report(CHOICE, "choice.md"),
    title="Self-imitation on CarRacing: the safety choices on selection tracks",
    note="Selection tracks (block 13): these choose the defaults; the fresh-track comparison "
    f"is selfimprove_carracing.py. {CAR_PAIRED} tracks. env steps / run: training rollouts "
    "(unperturbed and pushed runs); validation env steps: the keep rule's episodes.",
)
REHAB = Comparison(
    name="compare",
    methods=(
        Expert("expert", label="guideline clinician (expert)"),
        Agent("imitation", REHAB_START, label="safety-imitation start"),
        FromStart("ppo_lagrangian", "imitation", REHAB_PPO, label="PPO-Lagrangian + shield"),
        FromStart("selfimitation", "imitation", SELF, label="self-imitation"),
    ),
    task="rehab",
    demos=Path("data/rehab_demos"),
    out=Path("results/selfimprove/rehab"),
    train_seeds=(0, 1, 2),
    episodes=200,
    eval_seed=15,
    workers=0,
    reference="imitation",
    paired_metrics=("reward", "violating_sessions"),
    totals=("any_violating_session", "last_session_violation", "violation_steps"),
    per_seed=True,
    figures=(("learning_curves", "compare_learning_curves.png"),),
    title="Self-imitation vs PPO-Lagrangian on the rehabilitation pathway, equal env-step budgets",
    note=f"Reward: capacity gain (points). Both improvements from the same starts with "
    f"{REHAB_EPISODES * 30:,} training env steps per run. Paired rows: each agent against "
    "its own seed's start on the same patients. env steps / run: training rollouts; validation "
    "env steps / run: the episodes that pick (PPO) or accept (self-imitation) the final agent.",
)


def beyond_selection(
    base: Comparison,
    starts: tuple[Row, ...],
    candidates: dict[str, tuple[str, Any]],
    handovers: dict[str, tuple[str, HandoverConfig]],
    block: int,
    title: str,
    note: str,
) -> Comparison:
    """The beyond-the-expert selection table: ``starts`` (the expert and the start), each
    candidate (``name: (label, config)``) from the start, and each candidate under each of
    ``handovers`` (``tag: (shown, handover)``: rows ``<name>+<tag>``, labelled
    ``<label> + <shown>``)."""
    return replace(
        base,
        name="beyond_selection",
        runs="beyond",
        methods=(
            *starts,
            *(FromStart(n, "imitation", c, label=label) for n, (label, c) in candidates.items()),
            *(
                Handover(f"{n}+{tag}", n, h, label=f"{label} + {shown}")
                for n, (label, _) in candidates.items()
                for tag, (shown, h) in handovers.items()
            ),
        ),
        eval_seed=block,
        reference="expert",
        figures=(("learning_curves", "beyond_selection_learning_curves.png"),),
        title=title,
        note=note,
    )


def beyond_fresh(
    follows: str,
    rule: Rule,
    blocks: tuple[int, int],
    what: str,
    titles: tuple[str, str],
    note: str,
    stem: str = "beyond",
    suffix: str | None = None,
) -> dict[str, Fresh]:
    """The two fresh tables ``<stem>`` and ``<stem>_replication`` that follow a beyond-the-expert
    selection (``what``: tracks or patients), addressed by their names plus ``suffix`` (``None``:
    the selection's, what follows ``beyond_selection`` in its address)."""
    if suffix is None:
        suffix = follows.removeprefix("beyond_selection")
    (first, second), (title, again) = blocks, titles
    return {
        f"{stem}{suffix}": Fresh(
            stem, follows, (rule,), eval_seed=first, title=title,
            note=f"Fresh {what} (block {first}); {note}",
        ),
        f"{stem}_replication{suffix}": Fresh(
            f"{stem}_replication", follows, (rule,), eval_seed=second, title=again,
            note=f"Fresh {what} (block {second}, nothing changed but the {what}); {note}",
        ),
    }  # fmt: skip


CORNER = task_defaults("carracing").handover
"""The car's corner handover: the recommender's, and the candidates' at use."""
BEYOND_B = replace(SELF, keep_against="expert")
BEYOND_C = replace(BEYOND_B, handover=CORNER, pushes=LOOP_PUSHES["carracing"])
REHAB_HANDOVER = HandoverConfig(
    0.2, widths=(("heart_rate", 0.1), ("fatigue", 0.2), ("blood_pressure", 0.2)), fallback="cap"
)
"""The clinic's handover these tables ran with (per-dimension widths, the agent capped by the
guideline: ``results/rehab/handover_cap/choice.md``)."""
REHAB_B = replace(SELF, keep_against="expert")
REHAB_C = replace(REHAB_B, handover=REHAB_HANDOVER)
PAIRED_EXPERT = "Paired rows: each agent against the {} on the same {}."
CAR_RULE = Rule(
    "best_lower_bound", {"burden": 0.05},
    note="no selection episode beyond d_s, under 5% of steps deferred, the highest lower bound "
         "of the paired reward interval against the expert",
)  # fmt: skip
"""The car's rule, fixed with its first beyond design and kept by the second."""


def stall_restart(hold: int) -> HandoverConfig:
    """The corner handover with the expert restarting a car that stood still 20 steps, for
    ``hold`` steps."""
    return replace(CORNER, stall=20, stall_hold=hold)


BEYOND_STALL_NOTE = (
    "the handover row was chosen on 3 x 50 selection tracks of block 88 by the rule fixed "
    "before the run ({rule}). Paired rows: each agent against the expert on the same tracks."
)
BEYOND_D = ("D: C keeping the best 2 pushed runs per track", replace(BEYOND_C, keep_best=2))
"""Candidate D of the first design (its pick), the agents the later car designs hand over."""


def handover_design(
    ordinal: str,
    what: str,
    stem: str,
    handovers: dict[str, tuple[str, HandoverConfig]],
    blocks: tuple[int, int, int],
) -> dict[str, Comparison | Fresh]:
    """A later car design over D's agents: its selection table (D alone and under each of
    ``handovers`` on block ``blocks[0]``) and the two fresh tables the car's rule picks for
    (blocks ``blocks[1]``, ``blocks[2]``), named ``<stem>_selection``, ``<stem>``,
    ``<stem>_replication``; ``what``: the title's words for the handovers."""
    selection, first, second = blocks
    return {
        f"{stem}_selection": replace(
            beyond_selection(
                CAR, car_rows({}), {"si_explore_best2": BEYOND_D}, handovers, selection,
                f"Beyond the expert, {ordinal} design: D {what}, selection tracks (CarRacing)",
                f"Selection tracks (block {selection}): the rule picks one handover row for "
                f"the fresh blocks ({first}, {second}). "
                f"{PAIRED_EXPERT.format('expert', 'tracks')} steps deferred: the mean share of "
                "an episode's steps on which the expert acted.",
            ),
            name=f"{stem}_selection",
            figures=(),
        ),
        **beyond_fresh(
            f"{stem}_selection", CAR_RULE, (first, second), "tracks",
            (f"Beyond the expert, {ordinal} design: fresh tracks (CarRacing)",
             f"Beyond the expert, {ordinal} design: a second fresh block (CarRacing)"),
            BEYOND_STALL_NOTE.replace("block 88", f"block {selection}"), stem=stem, suffix="",
        ),
    }  # fmt: skip


BEYOND_STALL = handover_design(
    "second", "with a stalled car restarted by the expert", "beyond_stall",
    {"corner_stall50": ("corner handover, a stalled car restarted for 50 steps",
                        stall_restart(50)),
     "corner_stall100": ("corner handover, a stalled car restarted for 100 steps",
                         stall_restart(100))},
    (88, 89, 90),
)  # fmt: skip
"""The car's second beyond design, written after the first's pick (D + corner handover) met the
goal on block 25 (+1.3 [0.4, 2.3]) and missed it on block 26 (-4.2 [-20.8, 1.8], 1/3 seeds
above): every BC agent of the table, the start and each candidate alone or with the handover,
stopped on one track of block 26 (speed 0 from step ~590 to the time limit, 59-65% of the tiles,
no cost beyond d_s), where the expert finished. The same agents (D's runs) with the corner
handover plus the expert restarting a car whose costs stood still for 20 steps, for 50 or 100
steps; the same rule as the first design."""


def pace_rule(speed: float) -> HandoverConfig:
    """The second design's pick (corner handover, the stall restart (20, 100)) with the expert
    driving 50 steps where the car's speed stayed below ``speed`` for 10 steps."""
    return replace(stall_restart(100), pace=speed, pace_steps=10, pace_hold=50)


BEYOND_PACE = handover_design(
    "third", "with the expert driving where the car falls below pace", "beyond_pace",
    {"corner_stall100_pace30": ("corner handover, stall restart, the expert below speed 30",
                                pace_rule(30.0)),
     "corner_stall100_pace20": ("corner handover, stall restart, the expert below speed 20",
                                pace_rule(20.0))},
    (94, 95, 96),
)  # fmt: skip
"""The car's third beyond design, written after the second's pick (D + corner handover + stall
restart (20, 100)) was level with the expert on blocks 89 and 90 (+0.4 [-3.8, 2.5], +0.5
[-5.4, 3.3], 2/3 seeds above each): one long track a block where seed 0 covered 82% of the
tiles in the 1000 steps. Replayed (D seed 0, track 1082741827 of block 90 and 1082641835 of
block 89) the agent keeps the expert's pace for 600-800 steps, then after a corner brakes
lightly (0.1) without gas for 100-150 steps, its speed falling from about 35 to 0 while the
corner handover fires only briefly; the stall restart acts only once the car stands still.
The expert never drives below speed 41 after warm-up on those tracks, D elsewhere not below
33. The same agents (D's runs) with the second design's pick plus a pace rule
(``HandoverConfig.pace``): where the car's speed (privileged, as the expert's own reading)
stayed below 30 or 20 for 10 steps outside warm-up, the expert drives 50 steps; the same
rule as the first two designs."""


def pace30(**changes: Any) -> HandoverConfig:
    """The third design's pick (corner handover, stall restart (20, 100), the expert below speed
    30) with the corner zone's ``changes``."""
    return replace(pace_rule(30.0), **changes)


BEYOND_LEAN = handover_design(
    "fourth", "under a corner handover that defers less", "beyond_lean",
    {"pace30_hold3": ("the third pick, held 3 steps after the front zone (not 6)",
                      pace30(hold=3)),
     "pace30_look3": ("the third pick, looking 3 steps ahead (not 6)", pace30(lookahead=3)),
     "pace30_w15": ("the third pick, within 1.5 px of d_s (not 2)", pace30(width=1.5))},
    (94, 97, 98),
)  # fmt: skip
"""The car's fourth beyond design, written after the third's pick (D + corner handover + stall
restart (20, 100) + the expert below speed 30) was reliably above the expert on blocks 95 and 96
(+1.9 [0.9, 3.4], +2.2 [1.0, 3.9], 0 of 300 beyond d_s, 3/3 seeds each) but deferred 5.3% of
steps on block 95, above the 5% bound (4.4% on 96); the corner handover alone defers 5.2% there
(``beyond_pace_deferral``): the zone, not the restarts, sits at the bound. The same agents with
the third pick's corner zone made smaller in one of three ways: a hold of 3 steps after a front
zone step instead of 6, a lookahead of 3 steps instead of 6, or a width of 1.5 px instead of 2.
Selection on block 94 (the third design's selection tracks: its expert, start and D alone are
stored evaluations, and the runs folder is the same), the same rule (no selection episode beyond
d_s is what guards the smaller zone); fresh blocks 97 and 98, new to every table."""

STALL_ON_95 = replace(
    BEYOND_STALL["beyond_stall_selection"],
    name="beyond_pace_deferral",
    methods=tuple(
        m for m in BEYOND_STALL["beyond_stall_selection"].methods
        if m.name != "si_explore_best2+corner_stall50"
    ),
    eval_seed=95,
    title="Beyond the expert, third design: the second design's pick on the third's first "
    "fresh block (CarRacing)",
    note="A diagnostic, run after the third design's tables: the second design's pick (corner "
    "handover, stall restart (20, 100), no pace rule) on block 95, where the third's pick "
    "deferred 5.3% of steps; the expert, the start and D alone are the stored evaluations of "
    f"beyond_pace. {PAIRED_EXPERT.format('expert', 'tracks')} steps deferred: the mean share "
    "of an episode's steps on which the expert acted.",
)  # fmt: skip
"""The second design's pick on block 95, beside the third's (``beyond_pace``): how much of the
third's deferral the pace rule adds (a diagnostic on a block already used; it chooses
nothing)."""

CLINIC_RULE = Rule(
    "best_lower_bound", {"burden": 0.10, "beyond": "total_any_violating_session"},
    note="no selection programme beyond d_s, under 10% of sessions deferred, the highest "
         "lower bound of the paired reward interval against the guideline",
)  # fmt: skip
"""The clinic's rule, fixed with its first beyond design and kept by every later one."""
BEYOND = {
    "beyond_selection": beyond_selection(
        CAR, car_rows({}),
        {
            "si_agent_bar": ("A: self-imitation, defaults", SELF),
            "si_expert_bar": ("B: kept only above the expert's run", BEYOND_B),
            "si_explore": ("C: B exploring under the handover, full-size pushes", BEYOND_C),
            "si_explore_best2": ("D: C keeping the best 2 pushed runs per track",
                                 replace(BEYOND_C, keep_best=2)),
        },
        {"corner": ("corner handover", CORNER)}, 24,
        "Beyond the expert: self-imitation candidates with the corner handover, selection "
        "tracks (CarRacing)",
        "Selection tracks (block 24): the rule picks one handover row for the fresh blocks "
        f"(25, 26). {PAIRED_EXPERT.format('expert', 'tracks')} steps deferred: the mean share of "
        "an episode's steps on which the expert acted.",
    ),
    **beyond_fresh(
        "beyond_selection",
        CAR_RULE,
        (25, 26), "tracks",
        ("Beyond the expert: fresh tracks (CarRacing)",
         "Beyond the expert: a second fresh block (CarRacing)"),
        "the handover row was chosen on 3 x 50 selection tracks of block 24 by the rule fixed "
        f"before the run ({{rule}}). {PAIRED_EXPERT.format('expert', 'tracks')}",
    ),
    "beyond_selection_rehab": beyond_selection(
        REHAB, REHAB.methods[:2],
        {
            "si_agent_bar": ("A: self-imitation, defaults", SELF),
            "si_expert_bar": ("B: kept only above the guideline's run", REHAB_B),
            "si_explore": ("C: B exploring under the handover", REHAB_C),
            "si_explore_best2": ("D: C keeping the best 2 pushed runs per patient",
                                 replace(REHAB_C, keep_best=2)),
        },
        {"handover": ("handover", REHAB_HANDOVER)}, 63,
        "Beyond the guideline: self-imitation candidates with the clinic's handover, "
        "selection patients",
        "Selection patients (block 63): the rule picks one handover row for the fresh blocks "
        "(64, 65). Reward: capacity gain (points). "
        f"{PAIRED_EXPERT.format('guideline', 'patients')} sessions deferred: the mean share of "
        "a programme's sessions on which the guideline capped the agent.",
    ),
    **beyond_fresh(
        "beyond_selection_rehab",
        CLINIC_RULE,
        (64, 65), "patients",
        ("Beyond the guideline: fresh patients (rehab)",
         "Beyond the guideline: a second fresh block (rehab)"),
        "the handover row was chosen on 3 x 200 selection patients of block 63 by the rule "
        "fixed before the run ({rule}). Reward: capacity gain (points). "
        f"{PAIRED_EXPERT.format('guideline', 'patients')}",
    ),
}  # fmt: skip
"""Beyond the expert, in the car and the clinic: a selection table and two fresh ones each."""


REHAB_IMPROVE = ImproveConfig(eps=0.1)
"""The clinic's constrained improvement: the improvement table's settings (shield zone 0.1,
``results/improve/rehab/sweep/margin_sweep.md``), the rehab defaults otherwise."""
CLINIC_HANDOVERS = {  # tag: (label, handover)
    "handover": ("the task's handover", task_defaults("rehab").handover),
    "cap": ("the cap handover", REHAB_HANDOVER),
}
"""The clinic's two handovers: the task's (``TaskSpec.handover``, the recommender's: the
safest action in the zone) and the cap these tables' self-imitation ran under (the agent
capped by the guideline)."""
LAGRANGIAN_ROWS = {  # name: (label, config)
    "lagrangian": ("Lagrangian only", replace(REHAB_IMPROVE, shield=False, lagrangian=True)),
    "both": ("shield + Lagrangian", replace(REHAB_IMPROVE, shield=True, lagrangian=True)),
}
"""The improvers that beat the guideline on the improvement table (``results/improve/rehab/
improve.md``: +1.94 [1.26, 2.64] and +1.84 [1.29, 2.41], 1 and 3 of 600 beyond d_s)."""
CLINIC_LAGRANGIAN = replace(
    beyond_selection(
        REHAB, REHAB.methods[:2], LAGRANGIAN_ROWS, CLINIC_HANDOVERS, 70,
        "Beyond the guideline: the Lagrangian improvers under the clinic's handovers, "
        "selection patients",
        "Selection patients (block 70): the rule picks one handover row for the fresh blocks "
        "(71, 72). Reward: capacity gain (points). "
        f"{PAIRED_EXPERT.format('guideline', 'patients')} sessions deferred: the mean share of "
        "a programme's sessions on which the handover acted.",
    ),
    out=Path("results/selfimprove/rehab_lagrangian"),
)  # fmt: skip
"""The clinic's second beyond design, written after the first (``beyond_selection_rehab``)
showed every self-imitation candidate below the guideline: the two PPO-Lagrangian improvers
that beat it, each alone and under each of the clinic's two handovers."""
BEYOND_CLINIC = {
    "beyond_selection_rehab_lagrangian": CLINIC_LAGRANGIAN,
    **beyond_fresh(
        "beyond_selection_rehab_lagrangian",
        CLINIC_RULE,
        (71, 72), "patients",
        ("Beyond the guideline: the Lagrangian improvers, fresh patients (rehab)",
         "Beyond the guideline: the Lagrangian improvers, a second fresh block (rehab)"),
        "the handover row was chosen on 3 x 200 selection patients of block 70 by the rule "
        "fixed before the run ({rule}). Reward: capacity gain (points). "
        f"{PAIRED_EXPERT.format('guideline', 'patients')}",
    ),
}  # fmt: skip
"""The clinic's second design: a selection table and two fresh ones."""


def scaled_cap(k: float) -> HandoverConfig:
    """The cap handover (:data:`REHAB_HANDOVER`) with every width times ``k``."""
    widths = tuple((d, round(w * k, 6)) for d, w in REHAB_HANDOVER.widths)
    return replace(REHAB_HANDOVER, width=round(REHAB_HANDOVER.width * k, 6), widths=widths)


def cap_design(
    stem: str, caps: dict[str, tuple[str, HandoverConfig]], blocks: tuple[int, int, int], what: str
) -> dict[str, Any]:
    """A clinic design over the second design's agents (its runs): each Lagrangian improver
    alone and under each of ``caps``; a selection table ``<stem>_selection`` on ``blocks[0]``
    and fresh tables ``<stem>``, ``<stem>_replication`` on the other two, the rows the
    clinic's rule picks (``what``: the handovers, for the titles)."""
    selection, first, second = blocks
    rule_note = (
        f"the handover row was chosen on 3 x 200 selection patients of block {selection} by the "
        "rule fixed before the run ({rule}). Reward: capacity gain (points). "
        f"{PAIRED_EXPERT.format('guideline', 'patients')}"
    )
    follows = f"{stem}_selection_rehab_lagrangian"
    return {
        follows: replace(
            beyond_selection(
                REHAB, REHAB.methods[:2], LAGRANGIAN_ROWS, caps, selection,
                f"Beyond the guideline: the Lagrangian improvers under {what}, selection "
                "patients",
                f"Selection patients (block {selection}): the rule picks one handover row for "
                f"the fresh blocks ({first}, {second}). Reward: capacity gain (points). "
                f"{PAIRED_EXPERT.format('guideline', 'patients')} sessions deferred: the mean "
                "share of a programme's sessions on which the handover acted.",
            ),
            name=f"{stem}_selection",
            out=CLINIC_LAGRANGIAN.out,
        ),
        **beyond_fresh(
            follows, CLINIC_RULE, (first, second), "patients",
            (f"Beyond the guideline: {what}, fresh patients (rehab)",
             f"Beyond the guideline: {what}, a second fresh block (rehab)"),
            rule_note, stem=stem, suffix="_rehab_lagrangian",
        ),
    }  # fmt: skip


BEYOND_CLINIC_NARROW = cap_design(
    "beyond_narrow",
    {"cap_half": ("the cap at half width", scaled_cap(0.5)),
     "cap_quarter": ("the cap at a quarter width", scaled_cap(0.25))},
    (73, 74, 75), "narrower caps",
)  # fmt: skip
"""The clinic's third design, written after the second's cap rows stayed inside d_s with the
gain (+2.21 [1.75, 2.68], +1.68 [1.15, 2.34]) but acted on 13.5-17.9% of sessions, above the
10% bound: the cap at half and a quarter of its widths."""
BEYOND_CLINIC_MID = cap_design(
    "beyond_mid",
    {"cap_075": ("the cap at 0.75 width", scaled_cap(0.75)),
     "cap_060": ("the cap at 0.6 width", scaled_cap(0.6))},
    (76, 77, 78), "caps between",
)  # fmt: skip
"""The clinic's fourth design, written after the third: the half and quarter caps acted on
0.3-1.6% of sessions but let 2-5 of 600 selection programmes beyond d_s, the full cap 0 with
13.5-17.9%; widths between them, 0.75 and 0.6 of the cap's."""


BEYOND_CLINIC_EARLY = cap_design(
    "beyond_early",
    {"cap_060_ahead": ("the cap at 0.6 width, a session ahead",
                       replace(scaled_cap(0.6), lookahead=1)),
     "cap_060_hold": ("the cap at 0.6 width, held 2 sessions", replace(scaled_cap(0.6), hold=2))},
    (82, 83, 84), "a cap that acts earlier",
)  # fmt: skip
"""The clinic's fifth design, written after the fourth: the caps at 0.75 and 0.6 width acted on
1.9-4.8% of sessions, and each let exactly one selection programme beyond d_s, the same patient
for all four rows, on which the cap had acted on 40-70% of sessions: the crossing came from
load built up before the zone. The 0.6 cap acting a session earlier (the cost extrapolated one
session ahead) or held for 2 sessions after a zone session."""


def vs_expert(c: Comparison) -> Comparison:
    """``c`` paired against the expert: its runs and stored evaluations, no figure."""
    return replace(c, name="compare_vs_expert", runs="compare", reference="expert", figures=())


COMPARISONS = {
    "compare_carracing": CAR,
    "compare_vs_expert_carracing": vs_expert(CAR),
    "selection_carracing": CAR_SELECTION,
    "rounds_carracing": replace(
        CAR_SELECTION,
        name="rounds",
        runs="selection",
        methods=car_rows(CAR_ROUNDS),
        figures=(("learning_curves", "rounds_learning_curves.png"),),
        title="Self-imitation on CarRacing: more rounds, and smaller steps, on selection tracks",
        report=Report(CHOICE, "rounds_choice.md"),
    ),
    "compare_rehab": REHAB,
    "compare_vs_expert_rehab": vs_expert(REHAB),
    "selection_rehab": replace(
        REHAB,
        name="selection",
        methods=(
            *REHAB.methods[:2],
            *(FromStart(n, "imitation", c, label=label) for n, (label, c) in REHAB_CHOICES.items()),
        ),
        eval_seed=16,
        figures=(("learning_curves", "selection_learning_curves.png"),),
        report=Report(CHOICE, "choice.md"),
        title="Self-imitation on the rehabilitation pathway: the safety choices on selection "
        "patients",
        note="Selection patients (block 16): these choose the defaults; the fresh-patient "
        "comparison is selfimprove_rehab.py. Reward: capacity gain (points). Paired rows: each "
        "agent against its own seed's start on the same patients.",
    ),
    **BEYOND,
    **BEYOND_CLINIC,
    **BEYOND_CLINIC_NARROW,
    **BEYOND_CLINIC_MID,
    **BEYOND_CLINIC_EARLY,
    **BEYOND_STALL,
    **BEYOND_PACE,
    "beyond_pace_deferral": STALL_ON_95,
    **BEYOND_LEAN,
}
