"""The margin sweep's test: the tested candidates (``TESTED`` of ``margin_sweep.py``, each
used once, in order) on the 200 held-out patients of ``improve_rehab.py`` (evaluation seed
5). Run: ``safe-bc compare tune_jobs/compare/margin_sweep_test.py``; writes
``results/improve/rehab/sweep/sweep_test*``."""

from dataclasses import replace

from safe_bc.compare import sibling

sweep = sibling(__file__, "margin_sweep")

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
