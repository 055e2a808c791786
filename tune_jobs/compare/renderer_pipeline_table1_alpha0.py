"""The exact and the raster pipeline with Table 1's ``alpha=0 (rest=all)`` row: its
settings (selection, network, budget), its 8 training seeds and its 20 held-out tracks (seed
block 0); see ``renderer_pipeline.py``. Run: ``safe-bc compare
tune_jobs/compare/renderer_pipeline_table1_alpha0.py``; writes
``results/ablation/renderer/pipeline_table1_alpha0*``."""

from safe_bc.compare import sibling

pipeline = sibling(__file__, "renderer_pipeline")

COMPARISON = pipeline.table1_pipelines("pipeline_table1_alpha0", "alpha=0 (rest=all)", "alpha=0")
