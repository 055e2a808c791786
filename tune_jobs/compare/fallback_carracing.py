"""Diagnostic: would a safe fallback in critical states close CarRacing's violation gap?

The shield of ``safe_bc.improve`` hands critical states (measured cost within eps of d_s) to
the frozen imitation start. This comparison keeps every trained net of
``improve_carracing.py`` (it shares that comparison's runs folder, ``improve_runs/``: nothing
is retrained, and the rows both have are not re-evaluated) and adds rows whose critical
states go to the scripted expert instead (privileged: it reads the track, so it is *not* a
deployable CarRacing policy; in the clinic it stands for handing a critical decision back to
the clinician). Paired columns: the difference to the same seed's start without a fallback
on the same held-out tracks.

Run (after ``improve_carracing.py``): ``safe-bc compare
tune_jobs/compare/fallback_carracing.py``. Writes ``results/improve/carracing/fallback*``.
No committed tables: the earlier diagnostic was made on retired starts.
"""

from dataclasses import replace

from safe_bc.compare import Method, sibling

_base = sibling(__file__, "improve_carracing")

ROWS = ("imitation", "both", "ppo")
"""Rows evaluated with the expert as their fallback."""

COMPARISON = replace(
    _base.COMPARISON,
    name="fallback",
    runs="improve",
    methods=(
        *(m for m in _base.COMPARISON.methods if m.name in {"expert", *ROWS}),
        *(
            Method(f"{name}+expert", fallback_of=name, label=f"{name}, expert in critical states")
            for name in ROWS
        ),
    ),
    paired_metrics=("reward", "violation_steps"),
    per_seed=False,
    figures=(),
    title="Diagnostic: the expert as the shield's fallback (CarRacing)",
    note="Rows +expert: the same nets, the scripted expert (privileged) acting in their "
    "critical states; a bound on what a safe fallback would give, not a deployable policy.",
)
