"""CarRacing improvement with a smaller initial action noise (``init_std`` 0.03), shield +
Lagrangian only: the rows of ``improve_carracing.py`` with that one change, on 20 fresh
held-out tracks (seed block 10).

Run: ``safe-bc compare tune_jobs/compare/improve_carracing_std003.py``. Writes
``results/improve/carracing_std003/improve*``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import sibling

_base = sibling(__file__, "improve_carracing")

COMPARISON = replace(
    _base.COMPARISON,
    methods=_base.methods(replace(_base.BASE, init_std=0.03), {"both": _base.MODES["both"]}),
    out=Path("results/improve/carracing_std003"),
    episodes=20,
    eval_seed=10,
    title="Constrained improvement on CarRacing, initial action noise 0.03",
)
