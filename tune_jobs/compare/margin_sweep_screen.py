"""The margin sweep's screening: every candidate on training seed 0 and the selection
patients (see ``margin_sweep.py``). Run: ``safe-bc compare
tune_jobs/compare/margin_sweep_screen.py``; writes ``sweep_screen_seed0*`` there."""

import importlib.util
from dataclasses import replace
from pathlib import Path

_spec = importlib.util.spec_from_file_location(
    "margin_sweep", Path(__file__).with_name("margin_sweep.py")
)
assert _spec is not None and _spec.loader is not None
sweep = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sweep)

COMPARISON = replace(
    sweep.COMPARISON,
    name="sweep_screen_seed0",
    methods=sweep.sweep(list(sweep.CANDIDATES)),
    train_seeds=(0,),
    title="Margin sweep screening: every candidate on seed 0, selection patients",
)
