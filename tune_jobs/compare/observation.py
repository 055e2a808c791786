"""What should a CarRacing agent see? The observation ablation behind ``PreprocessConfig``'s
defaults, with the copycat check beside it.

Every cell (indicator bar cropped, kept, or kept with its steering indicator masked in
training and evaluation, ``PreprocessConfig.mask_steering``; x frame stack 1, 2, 4; x grey
or colour) is a row of plain behaviour cloning (alpha 0, the default network and budget) on
the default demonstrations; :data:`CELLS` get every training seed, :data:`SCREEN` (a screen:
reported, never deciding) seed 0 only. Every agent and the expert run on the same 20
*selection* tracks (held-out seed block 10, which no final table uses: Table 1 uses 0, the
study 1 and 2, the expert 3, the improvement 7).

Copycat check: the agents of every cell that sees the bar run a second time on the same
tracks with the steering indicator painted black (rows ``<cell>/steer_masked``); the
evaluation path records how much the steering follows itself (``steer_autocorr``,
``steer_change``) for every episode.

Run: ``safe-bc compare tune_jobs/compare/observation.py`` (hours on 2 cores; resumes per
cell and seed), then ``python -m scripts.observation_choice`` (the chosen default, the
paired and copycat tables, ``observation.md`` and the figure, from the episode table).
Writes ``results/ablation/observation/observation*``. Cell names are the keys of the
committed tables, which seed their bootstrap.
"""

import itertools
from pathlib import Path

from safe_bc.bc.config import BCConfig, NetworkConfig, PreprocessConfig, TrainConfig
from safe_bc.compare import Comparison, Method
from safe_bc.selection import SelectionConfig

MASKED = "/steer_masked"
"""Suffix of the rows evaluated with the steering indicator masked."""


def cell_name(pre: PreprocessConfig) -> str:
    """``bar_grey_k1``-style name of an observation setting.

    >>> cell_name(PreprocessConfig(crop_bar=False, mask_steering=True, grayscale=True))
    'bar-nosteer_grey_k1'
    """
    bar = "nobar" if pre.crop_bar else "bar-nosteer" if pre.mask_steering else "bar"
    colour = "grey" if pre.grayscale else "rgb"
    return f"{bar}_{colour}_k{pre.frame_stack}"


def all_cells() -> dict[str, PreprocessConfig]:
    """The full factorial by name: bar cropped / kept / kept with its steering indicator
    masked x grey/colour x frame stack 1, 2, 4."""
    bars = ((True, False), (False, False), (False, True))  # (crop_bar, mask_steering)
    pres = [
        PreprocessConfig(crop_bar=crop, mask_steering=mask, grayscale=grey, frame_stack=k)
        for (crop, mask), grey, k in itertools.product(bars, (True, False), (1, 2, 4))
    ]
    return {cell_name(p): p for p in pres}


def rows(
    name: str, pre: PreprocessConfig, *, batches: int | None = None, channels=None, seeds=()
) -> list[Method]:
    """A cell's BC row (plain BC, alpha 0) and, when it sees the indicator, its masked row."""
    net = NetworkConfig(channels=channels) if channels else NetworkConfig()
    bc = BCConfig(preprocess=pre, network=net, train=TrainConfig(batches=batches or 2000))
    out = [Method(name, selection=SelectionConfig(eps=2.0, alpha=0.0), bc=bc, seeds=seeds)]
    if not (pre.crop_bar or pre.mask_steering):
        out.append(Method(name + MASKED, masked_of=name))
    return out


CELLS = ["nobar_grey_k1", "nobar_grey_k2", "bar_grey_k1", "bar_grey_k4", "bar_rgb_k1",
         "bar_rgb_k4", "bar-nosteer_grey_k4", "bar-nosteer_rgb_k1"]  # fmt: skip
"""Cells with every training seed (the committed run's ``--cells``)."""
SCREEN = ["nobar_grey_k4", "nobar_rgb_k1", "nobar_rgb_k2", "nobar_rgb_k4", "bar_grey_k2",
          "bar_rgb_k2"]  # fmt: skip
"""Cells screened with training seed 0 only."""
BASELINE = "nobar_grey_k1"
"""The cell the others are paired with."""

_cells = all_cells()
COMPARISON = Comparison(
    name="observation",
    methods=(
        *(r for c in CELLS for r in rows(c, _cells[c])),
        *(r for c in SCREEN for r in rows(c, _cells[c], seeds=(0,))),
        Method("expert", expert=True),
    ),
    task="carracing",
    out=Path("results/ablation/observation"),
    train_seeds=(0, 1, 2),
    episodes=20,
    eval_seed=10,
    reference=BASELINE,
    paired_metrics=("reward", "violation_steps", "any_violation"),
    title="Observation ablation (CarRacing, plain BC)",
)
