"""The margin sweep's test: the tested candidates (``TESTED`` of ``margin_sweep.py``, each
used once, in order) on the 200 held-out patients of ``improve_rehab.py`` (evaluation seed
5). Run: ``safe-bc compare tune_jobs/compare/margin_sweep_test.py``; writes
``results/improve/rehab/sweep/sweep_test*``."""

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
    name="sweep_test",
    methods=sweep.sweep(sweep.TESTED),
    episodes=200,
    eval_seed=5,
    tracks="heldout",
    first_track=0,
    title="Margin sweep: tested candidates on the held-out patients",
)
