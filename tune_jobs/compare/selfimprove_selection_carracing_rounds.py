"""Self-imitation's rounds on CarRacing: more rounds of self-imitation, and more rounds
with smaller steps, on the same selection tracks as ``selfimprove_selection_carracing.py``.

Rows: the expert, the start and the defaults (shared with that file: same runs and stored
evaluations, ``runs="selection"``), ``rounds4`` (4 rounds against 2, same pushes: its first
two rounds are the defaults' own, copied, since a round never depends on how many follow) and
``rounds4_small`` (4 rounds with pushes of half the size: offsets halved, scales halfway to
1). 3 training seeds x 50 tracks of block 13.

Run after that file:
``safe-bc compare tune_jobs/compare/selfimprove_selection_carracing_rounds.py``.
Writes ``results/selfimprove/carracing/rounds*``.
"""

from dataclasses import replace

from safe_bc.compare import sibling

_selection = sibling(__file__, "selfimprove_selection_carracing")

COMPARISON = replace(
    _selection.COMPARISON,
    name="rounds",
    runs="selection",
    methods=_selection.rows({"defaults": _selection.CHOICES["defaults"], **_selection.ROUNDS}),
    figures=(("learning_curves", "rounds_learning_curves.png"),),
    title="Self-imitation on CarRacing: more rounds, and smaller steps, on selection tracks",
)
