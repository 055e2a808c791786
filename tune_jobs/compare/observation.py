"""What a CarRacing agent sees and how it trains: plain behaviour cloning on selection tracks.

Every row is plain behaviour cloning (alpha 0, eps 2 px, 2,000 batches of 64, the default
network unless the row says otherwise) on the default demonstrations, with 3 training seeds;
every agent and the expert run on the same 20 *selection* tracks (held-out seed block 10):
these tables choose ``PreprocessConfig``'s and ``TrainConfig``'s defaults, so no reported
table uses these tracks as fresh ones. Row names are the keys of the committed tables, which
seed the bootstrap.

* ``observation``: the full factorial (indicator bar cropped ``nobar``, kept ``bar``, or kept
  with its steering indicator masked ``bar-nosteer``; grey or colour; frame stack 1, 2, 4);
  :data:`CELLS` with every training seed, :data:`SCREEN` with seed 0 only (a screen: reported,
  never deciding). The copycat check: the agents of every cell that sees the bar run again with
  the steering indicator painted black (rows ``<cell>/steer_masked``).
* ``batch``, ``budget``, ``network``, ``resize``: the chosen cell (:data:`CHOSEN`) along one
  axis each: batch size 64 / 32; 1,000 / 2,000 / 4,000 batches; conv channels 8-16-16 /
  16-32-32 / 32-64-64; the full 96x96 frame / 64x64 / 48x48 (area interpolation).

Run: ``safe-bc compare tune_jobs/compare/observation.py --name NAME``. Each table's report step
(:data:`CHOICE`, :mod:`safe_bc.compare.observation_choice`) then writes, beside it, the default
it supports from its episodes: ``summary.parquet``, ``paired.parquet``, ``copycat.parquet``,
``paired_chosen.parquet``, ``NAME.md`` (in place of the table's own Markdown) and ``NAME.png``,
headed by the comparison's title; ``--report-only`` reruns only the step.
"""

import itertools
from dataclasses import replace
from pathlib import Path

from safe_bc.bc.config import BCConfig, NetworkConfig, PreprocessConfig, TrainConfig
from safe_bc.compare.observation_choice import MASKED
from safe_bc.compare.spec import Agent, Comparison, Expert, Report, Row, View
from safe_bc.selection import SelectionConfig


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


def rows(name: str, bc: BCConfig, seeds: tuple[int, ...] = ()) -> list[Row]:
    """A cell's plain-BC row and, when it sees the steering indicator, its masked row."""
    out: list[Row] = [Agent(name, SelectionConfig(eps=2.0, alpha=0.0), bc=bc, seeds=seeds)]
    if not (bc.preprocess.crop_bar or bc.preprocess.mask_steering):
        out.append(View(name + MASKED, name, masked=True))
    return out


def bc(pre: PreprocessConfig, **train: int) -> BCConfig:
    """BC on ``pre`` with the default network and 2,000 batches (``train``: other fields)."""
    return BCConfig(
        preprocess=pre, network=NetworkConfig(), train=TrainConfig(**{"batches": 2000, **train})
    )


CELLS = ["nobar_grey_k1", "nobar_grey_k2", "bar_grey_k1", "bar_grey_k4", "bar_rgb_k1",
         "bar_rgb_k4", "bar-nosteer_grey_k4", "bar-nosteer_rgb_k1"]  # fmt: skip
"""Cells with every training seed."""
SCREEN = ["nobar_grey_k4", "nobar_rgb_k1", "nobar_rgb_k2", "nobar_rgb_k4", "bar_grey_k2",
          "bar_rgb_k2"]  # fmt: skip
"""Cells screened with training seed 0 only."""
BASELINE = "nobar_grey_k1"
"""The cell the factorial's others are paired with."""
CHOSEN = "bar-nosteer_rgb_k1"
"""The factorial's choice, the cell of the one-axis tables."""
_cells = all_cells()
_pre = _cells[CHOSEN]
CHOICE = Report("safe_bc.compare.observation_choice:report", reads=("episodes", "training"))
"""Every table's report step: the default it supports, from its episodes and training table."""


def table(name: str, methods: list[Row], reference: str, title: str, out: str = "") -> Comparison:
    """A table on the 20 selection tracks of block 10, paired with ``reference``."""
    return Comparison(
        name=name,
        methods=(*methods, Expert("expert")),
        task="carracing",
        out=Path("results/ablation") / (out or name),
        train_seeds=(0, 1, 2),
        episodes=20,
        eval_seed=10,
        reference=reference,
        paired_metrics=("reward", "violation_steps", "any_violation"),
        title=title,
        shares_tracks_with=SELECTION_BLOCK,
        report=CHOICE,
    )


def axis(name: str, settings: dict[str, BCConfig], reference: str, title: str) -> Comparison:
    """The chosen cell along one axis: a row per named setting."""
    return table(name, [r for n, b in settings.items() for r in rows(n, b)], reference, title)


SELECTION_BLOCK = tuple(
    f"results/ablation/{n}/{n}" for n in ("observation", "batch", "budget", "network", "resize")
)
"""The tables on block 10, which share its tracks by design."""

COMPARISONS = (
    table(
        "observation",
        [
            *(r for c in CELLS for r in rows(c, bc(_cells[c]))),
            *(r for c in SCREEN for r in rows(c, bc(_cells[c]), seeds=(0,))),
        ],
        BASELINE,
        "Observation ablation (CarRacing, plain BC)",
    ),
    axis(
        "batch",
        {CHOSEN: bc(_pre), f"{CHOSEN}@bs32": bc(_pre, batch_size=32)},
        CHOSEN,
        "Batch size (CarRacing, plain BC)",
    ),
    axis(
        "budget",
        {f"{CHOSEN}@b{b}": bc(_pre, batches=b) for b in (1000, 2000, 4000)},
        f"{CHOSEN}@b2000",
        "Training budget (CarRacing, plain BC)",
    ),
    axis(
        "network",
        {
            f"{CHOSEN}@c{'-'.join(map(str, c))}": BCConfig(
                preprocess=_pre, network=NetworkConfig(channels=c), train=TrainConfig(batches=2000)
            )
            for c in ((8, 16, 16), (16, 32, 32), (32, 64, 64))
        },
        f"{CHOSEN}@c16-32-32",
        "Network width (CarRacing, plain BC)",
    ),
    axis(
        "resize",
        {CHOSEN: bc(_pre), **{f"{CHOSEN}@r{s}": bc(replace(_pre, resize=s)) for s in (64, 48)}},
        CHOSEN,
        "Frame size (CarRacing, plain BC)",
    ),
)
