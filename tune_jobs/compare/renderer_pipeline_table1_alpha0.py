"""The exact and the raster pipeline with Table 1's ``alpha=0 (rest=all)`` row: its
settings (selection, network, budget), its 8 training seeds and its 20 held-out tracks (seed
block 0); see ``renderer_pipeline.py``. Run: ``safe-bc compare
tune_jobs/compare/renderer_pipeline_table1_alpha0.py``; writes
``results/ablation/renderer/pipeline_table1_alpha0*``."""

import importlib.util
from pathlib import Path

from safe_bc.reproduce import ReproduceConfig

_spec = importlib.util.spec_from_file_location(
    "renderer_pipeline", Path(__file__).with_name("renderer_pipeline.py")
)
assert _spec is not None and _spec.loader is not None
pipeline = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(pipeline)

TABLE1 = ReproduceConfig().comparison()
ROW = TABLE1.method("alpha=0 (rest=all)")
assert ROW.selection is not None

COMPARISON = pipeline.pipelines(
    "pipeline_table1_alpha0",
    ROW.selection,
    ROW.bc or TABLE1.bc,
    train_seeds=TABLE1.train_seeds,
    eval_seed=TABLE1.eval_seed,
    title="Exact pipeline vs raster pipeline, Table 1's alpha=0 row",
)
