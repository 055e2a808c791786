"""``selfimprove_carracing.py`` paired against the expert (standing in for every training seed on
the same tracks): the same rows, runs and stored evaluations (``runs="compare"``), nothing
trained or evaluated again. Run it after that file:
``safe-bc compare tune_jobs/compare/selfimprove_carracing_vs_expert.py``."""

from dataclasses import replace

from safe_bc.compare import sibling

COMPARISON = replace(
    sibling(__file__, "selfimprove_carracing").COMPARISON,
    name="compare_vs_expert",
    runs="compare",
    reference="expert",
    figures=(),
)
