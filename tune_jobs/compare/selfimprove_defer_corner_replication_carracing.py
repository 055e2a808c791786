"""The corner handover again on a second fresh block, a replication of
``selfimprove_defer_corner_carracing.py`` (block 22, 0 of 150 beyond d_s) with nothing
changed but the tracks: the same row (the rule's choice on the selection tracks), 3 training
seeds x 50 fresh tracks of held-out seed block 23, which no other table uses. Decided after
block 22's table and before this one was run; whatever it shows is reported beside block 22.

Shares the comparison's runs (``runs="compare"``). Run: ``safe-bc compare
tune_jobs/compare/selfimprove_defer_corner_replication_carracing.py``. Writes
``results/selfimprove/carracing/defer_corner_replication*``.
"""

from dataclasses import replace

from safe_bc.compare import sibling

_fresh = sibling(__file__, "selfimprove_defer_corner_carracing")

COMPARISON = replace(
    _fresh.COMPARISON,
    name="defer_corner_replication",
    eval_seed=23,
    title="Self-imitation with a handover that lasts through the corner: a second fresh block "
    "(CarRacing)",
    note=_fresh.COMPARISON.note.replace(
        "Fresh tracks (block 22)", "Fresh tracks (block 23, a replication of block 22's table)"
    ),
)
