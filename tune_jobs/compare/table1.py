"""Table 1 of the paper, rerun with confidence intervals (``safe-bc reproduce`` runs the same
comparison).

Rows: the alpha mix at alpha 0 (plain BC, the paired columns' reference), 0.1, 0.5, 0.8 and
1 (BC on T_eps only), OSRL's BC-Safe (K = 20) and cost-weighted BC (beta = 9), each with 11
training seeds, and the expert; every agent on the same 10 held-out tracks of block 0 (the
split the evaluation-budget measurement chose, ``results/ablation/eval_budget/``).

Run: ``safe-bc compare tune_jobs/compare/table1.py`` (353 s with 16 workers on 16 cores;
resumes per method and seed). Writes ``results/table1*.parquet``, ``results/table1.md``,
``results/fig4_alpha.png``, ``results/fig5_6_traces.png``.
"""

from safe_bc.compare.reproduce import ReproduceConfig

COMPARISONS = (ReproduceConfig().comparison(),)
