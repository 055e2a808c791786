"""The safety choices of self-imitation on the rehabilitation pathway, measured on *selection*
patients, as ``selfimprove_selection_carracing.py`` does on tracks.

Rows: the guideline clinician (the expert); the safety-imitation start (BC with alpha 0.5 on
T_eps, eps 0.05, as in ``improve_rehab.py`` and ``selfimprove_rehab.py``; the paired columns'
reference); self-imitation with the package's defaults and the rehab pushes (intensity and
duration +-0.05) from each seed's start; one row per safety choice, each changing one field:

* ``margin``: kept data stay :data:`MARGIN` inside d_s (half the selection's eps, as 1 px is
  half of CarRacing's 2 px) against 0;
* ``segment``: kept 10-session segments (``keep_unit="segment"``, ``segment_steps=10``: a
  programme has 30 sessions) against whole programmes;
* ``critical``: kept rows join T_eps (``kept_in="critical"``) against the rest pool only;
* ``no_backoff``: pushes also in the critical zone (``backoff=False``);
* ``rounds4``: 4 rounds against 2, same pushes;
* ``rounds4_small``: 4 rounds with pushes of half the size.

3 training seeds x 200 patients of held-out seed block 16, which no other table uses (the
fresh-patient comparison is ``selfimprove_rehab.py``, block 15). Rollouts in the driver
(``workers=0``: rehab episodes are cheap).

Run: ``safe-bc compare tune_jobs/compare/selfimprove_selection_rehab.py`` (resumes per method,
seed and round). Writes ``results/selfimprove/rehab/selection*``.
"""

from dataclasses import replace

from safe_bc.compare import Method, sibling
from safe_bc.selection import SelectionConfig
from safe_bc.selfimprove.config import LOOP_PUSHES, SelfImproveConfig

START = SelectionConfig(eps=0.05, alpha=0.5)
"""The starts' selection (``improve_rehab.py``)."""
MARGIN = START.eps / 2
"""The margin row's distance inside d_s (cost units)."""
DEFAULT = SelfImproveConfig(rounds=2, pushes=LOOP_PUSHES["rehab"], kept_in="rest")
"""The package's defaults when this table was made (before it chose ``kept_in="critical"``)."""
_half = sibling(__file__, "selfimprove_selection_carracing").half

CHOICES = {  # name: (label, config)
    "defaults": ("self-imitation, defaults", DEFAULT),
    "margin": (f"margin {MARGIN:g} inside d_s", replace(DEFAULT, margin=MARGIN)),
    "segment": (
        "kept segments (10 sessions)",
        replace(DEFAULT, keep_unit="segment", segment_steps=10),
    ),
    "critical": ("kept rows in T_eps", replace(DEFAULT, kept_in="critical")),
    "no_backoff": ("no back-off in the critical zone", replace(DEFAULT, backoff=False)),
    "rounds4": ("4 rounds", replace(DEFAULT, rounds=4)),
    "rounds4_small": (
        "4 rounds, half-size pushes",
        replace(DEFAULT, rounds=4, pushes=tuple(_half(s) for s in LOOP_PUSHES["rehab"])),
    ),
}

COMPARISON = replace(
    sibling(__file__, "selfimprove_rehab").COMPARISON,  # task, demos, seeds, patients, metrics
    name="selection",
    methods=(
        Method("expert", expert=True, label="guideline clinician (expert)"),
        Method("imitation", selection=START, label="safety-imitation start"),
        *(
            Method(name, selfimprove=config, start="imitation", label=label)
            for name, (label, config) in CHOICES.items()
        ),
    ),
    eval_seed=16,
    figures=(("learning_curves", "selection_learning_curves.png"),),
    title="Self-imitation on the rehabilitation pathway: the safety choices on selection patients",
    note="Selection patients (block 16): these choose the defaults; the fresh-patient "
    "comparison is selfimprove_rehab.py. Reward: capacity gain (points). Paired rows: each "
    "agent against its own seed's start on the same patients.",
)
