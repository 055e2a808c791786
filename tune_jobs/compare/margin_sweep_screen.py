"""The margin sweep's screening: every candidate on training seed 0 and the selection
patients (see ``margin_sweep.py``). Run: ``safe-bc compare
tune_jobs/compare/margin_sweep_screen.py``; writes ``sweep_screen_seed0*`` there."""

from dataclasses import replace

from safe_bc.compare import sibling

sweep = sibling(__file__, "margin_sweep")

COMPARISON = replace(
    sweep.COMPARISON,
    name="sweep_screen_seed0",
    methods=sweep.sweep(list(sweep.CANDIDATES)),
    train_seeds=(0,),
    title="Margin sweep screening: every candidate on seed 0, selection patients",
)
