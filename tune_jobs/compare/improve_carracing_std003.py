"""CarRacing improvement with a smaller initial action noise (``init_std`` 0.03), shield +
Lagrangian only: the rows of ``improve_carracing.py`` with that one change, on 20 fresh
held-out tracks (seed block 10).

Run: ``safe-bc compare tune_jobs/compare/improve_carracing_std003.py``. Writes
``results/improve/carracing_std003/improve*``.
"""

import importlib.util
from dataclasses import replace
from pathlib import Path

_spec = importlib.util.spec_from_file_location(
    "improve_carracing", Path(__file__).with_name("improve_carracing.py")
)
assert _spec is not None and _spec.loader is not None
_base = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_base)

COMPARISON = replace(
    _base.COMPARISON,
    methods=_base.methods(replace(_base.BASE, init_std=0.03), {"both": _base.MODES["both"]}),
    out=Path("results/improve/carracing_std003"),
    episodes=20,
    eval_seed=10,
    title="Constrained improvement on CarRacing, initial action noise 0.03",
)
