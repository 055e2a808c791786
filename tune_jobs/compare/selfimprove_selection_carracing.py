"""Which safety choices of self-imitation to keep, measured on CarRacing's
*selection* tracks.

Rows: the expert; the safety-imitation start (BC with alpha 0.1 on T_eps, as in
``improve_carracing.py``; the paired columns' reference); the self-imitation run with the
package's defaults (:class:`~safe_bc.selfimprove.config.SelfImproveConfig`: episode keeps,
margin 0, kept rows in the rest pool, back-off on, 2 rounds) from each seed's start; and one
row per safety choice, each changing one field of the defaults:

* ``margin1px``: kept data stay 1 px inside d_s (``margin=1.0``) against 0;
* ``segment``: kept 50-step segments (``keep_unit="segment"``) against whole episodes;
* ``critical``: kept rows join T_eps (``kept_in="critical"``) against the rest pool only;
* ``no_backoff``: pushes also in the critical zone (``backoff=False``);
* ``alpha05``: half of every retraining batch from the demonstrations' ``T_eps``
  (``alpha=0.5``: the paper's mechanism, to carry the expert's behaviour near the limit)
  against the start's 0.1 (the start itself is unchanged: one set of starts serves every row);
* ``bound05``: the keep rule accepts a round only when the one-sided 95% Clopper-Pearson bound
  on its validation episodes beyond d_s is below 5% (``beyond_limit=0.05``) against 10%; it
  needs 64 validation tracks (``validation_episodes=64``: 0 of 64 bounds the share at 4.6%,
  0 of 32 only at 8.9%), so this row changes both fields.

More rounds (``rounds4``: 4 against 2, same pushes; ``rounds4_small``: 4 rounds with pushes of
half the size) are the sibling file ``selfimprove_selection_carracing_rounds.py``, which
shares these runs (``runs="selection"``: the defaults' first two rounds are the 4-round row's
first two) and is run after this one.

The last two rows were added after the table's first five (same starts, tracks and rule;
``scripts/selfimprove_choice.py`` then reads all seven). Not covered: the alpha of the
start's own training (a row per start alpha would need its own starts).

3 training seeds x 50 tracks of held-out seed block 13, which no other table uses (Table 1 0,
the study 1 and 2, the expert jobs 3, rehab 5, improvement 7 and 10, observation 10,
renderer 11, deferral 11 and 12, the item-3 comparisons 14 and 15): these tracks choose the
defaults, so the item-3 tables (``selfimprove_carracing.py``) report fresh ones. The
self-imitation runs roll out on :data:`WORKERS` Ray actors (results do not depend on it; wall
time here is not compared).

Run: ``safe-bc compare tune_jobs/compare/selfimprove_selection_carracing.py`` (resumes per
method, seed and round; ``--cell METHOD:SEED --workers 0`` runs one cell in its own process,
so the cells can run side by side). Expected env steps per 2-round run: 2 x 24 tracks x (1 +
5 pushes) episodes of at most 1000 steps (288,000) in rollouts and 3 x 32 validation episodes
(96,000). The rule that turns the table into defaults: ``scripts/selfimprove_choice.py``.
Writes ``results/selfimprove/carracing/selection*``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import Comparison, Method
from safe_bc.selection import SelectionConfig
from safe_bc.selfimprove.config import LOOP_PUSHES, SelfImproveConfig, parse_push

WORKERS = 8
"""Rollout actors of each self-imitation run."""
START_ALPHA = 0.1
"""Safety focus of the starts (as in ``improve_carracing.py``)."""
DEFAULT = SelfImproveConfig(
    rounds=2, pushes=LOOP_PUSHES["carracing"], kept_in="rest", workers=WORKERS
)
"""The package's defaults when this table was made (before the rounds table chose 4 rounds of
half-size pushes): 2 rounds of the user's loop's pushes, kept rows in the rest pool."""


def half(spec: str) -> str:
    """A push of half the size: offsets halved, scales halfway to 1.

    >>> [half(s) for s in ("1+0.03", "2*0.8", "0-0.1")]
    ['1+0.015', '2*0.9', '0-0.05']
    """
    terms = []
    for dim, op, value in parse_push(spec):
        terms.append(f"{dim}*{1 - (1 - value) / 2:g}" if op == "*" else f"{dim}{value / 2:+g}")
    return ",".join(terms)


CHOICES = {  # name: (label, config)
    "defaults": ("self-imitation, defaults", DEFAULT),
    "margin1px": ("margin 1 px inside d_s", replace(DEFAULT, margin=1.0)),
    "segment": ("kept segments (50 steps)", replace(DEFAULT, keep_unit="segment")),
    "critical": ("kept rows in T_eps", replace(DEFAULT, kept_in="critical")),
    "no_backoff": ("no back-off in the critical zone", replace(DEFAULT, backoff=False)),
    "alpha05": ("T_eps half of each retraining batch", replace(DEFAULT, alpha=0.5)),
    "bound05": (
        "keep rule bound 5% (64 validation tracks)",
        replace(DEFAULT, beyond_limit=0.05, validation_episodes=64),
    ),
}
"""The safety filters, one field of the defaults each (this file's rows)."""
ROUNDS = {  # name: (label, config)
    "rounds4": ("4 rounds", replace(DEFAULT, rounds=4)),
    "rounds4_small": (
        "4 rounds, half-size pushes",
        replace(DEFAULT, rounds=4, pushes=tuple(half(s) for s in LOOP_PUSHES["carracing"])),
    ),
}
"""More rounds, with and without smaller steps (``selfimprove_selection_carracing_rounds.py``)."""


def rows(choices: dict) -> tuple[Method, ...]:
    """The expert, the start and one self-imitation row per choice."""
    return (
        Method("expert", expert=True, label="expert (scripted, privileged)"),
        Method(
            "imitation",
            selection=SelectionConfig(eps=2.0, alpha=START_ALPHA),
            label=f"safety-imitation start (alpha {START_ALPHA})",
        ),
        *(
            Method(name, selfimprove=config, start="imitation", label=label)
            for name, (label, config) in choices.items()
        ),
    )


COMPARISON = Comparison(
    name="selection",
    methods=rows(CHOICES),
    task="carracing",
    out=Path("results/selfimprove/carracing"),
    train_seeds=(0, 1, 2),
    episodes=50,
    eval_seed=13,
    reference="imitation",
    paired_metrics=("reward", "violation_steps"),
    per_seed=True,
    figures=(("learning_curves", "selection_learning_curves.png"),),
    title="Self-imitation on CarRacing: the safety choices on selection tracks",
    note="Selection tracks (block 13): these choose the defaults; the fresh-track comparison "
    "is selfimprove_carracing.py. Paired rows: each agent against its own seed's start on the "
    "same tracks. env steps / run: training rollouts (unperturbed and pushed runs); "
    "validation env steps: the keep rule's episodes.",
)
