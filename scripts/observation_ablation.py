"""What should a CarRacing agent see? The observation ablation behind ``PreprocessConfig``'s
defaults, with the copycat check beside it.

    python -m scripts.observation_ablation --processes 2        # all 18 cells x 3 seeds
    python -m scripts.observation_ablation --seeds 0 --episodes 2 --batches 50 \
        --cells bar_grey_k1 nobar_grey_k1 --out /tmp/obs_smoke   # a quick look

Every cell (indicator bar cropped, kept, or kept with its steering indicator masked in
training and evaluation (``PreprocessConfig.mask_steering``) x frame stack 1, 2, 4 x grey or
colour) trains
plain behaviour cloning (alpha 0, the default network and budget) on the default
demonstrations with ``--seeds`` training seeds, and evaluates each agent on the same
``--episodes`` *selection* tracks (held-out seed block ``--eval-seed`` = 10, which no final
table uses: Table 1 uses 0, the study 1 and 2, the expert 3, the improvement 7). The expert
drives the same tracks as a reference.

**Copycat check.** The bar shows the current steering angle (rows 84-95, columns 36-61 of
the frame: ``safe_bc.bc.preprocess.STEERING_INDICATOR``), a cue behaviour cloning is known to
lean on (copy your own previous action). Every agent that sees the bar is evaluated a second
time on the same
tracks with that region painted black (the bar's background: the indicator at zero
steering), and every episode records how much the steering follows itself
(``steer_autocorr``, the lag-1 autocorrelation of the steering actions over the scored steps,
and ``steer_change``, the mean absolute step-to-step change), for the agents and the expert.
An agent that copies its previous steering loses more when the indicator is masked, and
steers more sluggishly than the expert.

Each (cell, seed) is one job (train, then evaluate); finished jobs are cached in
``OUT/runs/`` keyed by their settings, so the command resumes. Intervals are crossed
bootstraps over training seeds x tracks (:func:`safe_bc.metrics.summarize_crossed`,
:func:`safe_bc.metrics.paired_crossed`; bootstrap seed 0).

Writes ``OUT/episodes.parquet``, ``OUT/summary.parquet``, ``OUT/paired.parquet``,
``OUT/copycat.parquet``, ``OUT/observation.md`` and ``OUT/observation.png``.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import multiprocessing
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.bc.config import BCConfig, NetworkConfig, PreprocessConfig, TrainConfig
from safe_bc.bc.preprocess import STEERING_INDICATOR
from safe_bc.data.store import read_table, write_table_atomic, write_text_atomic
from safe_bc.metrics import paired_crossed
from safe_bc.provenance import run_metadata

SELECTION_EVAL_SEED = 10
"""Held-out track block of this ablation (no final table uses it)."""

REPORT_METRICS = (
    "reward",
    "any_violation",
    "violation_steps",
    "offroad_steps",
    "safety_mean",
    "steer_autocorr",
    "steer_change",
)


def cell_name(pre: PreprocessConfig) -> str:
    """``bar_grey_k1``-style name of an observation setting.

    >>> cell_name(PreprocessConfig(crop_bar=False, mask_steering=False, grayscale=False,
    ...                            frame_stack=4))
    'bar_rgb_k4'
    >>> cell_name(PreprocessConfig(crop_bar=False, mask_steering=True, grayscale=True))
    'bar-nosteer_grey_k1'
    """
    bar = "nobar" if pre.crop_bar else "bar-nosteer" if pre.mask_steering else "bar"
    colour = "grey" if pre.grayscale else "rgb"
    return f"{bar}_{colour}_k{pre.frame_stack}"


def all_cells() -> list[PreprocessConfig]:
    """The full factorial: bar cropped / kept / kept with its steering indicator masked x
    grey/colour x frame stack 1, 2, 4."""
    bars = ((True, False), (False, False), (False, True))  # (crop_bar, mask_steering)
    return [
        PreprocessConfig(crop_bar=crop, mask_steering=mask, grayscale=grey, frame_stack=k)
        for (crop, mask), grey, k in itertools.product(bars, (True, False), (1, 2, 4))
    ]


def steering_follow(steer: np.ndarray) -> tuple[float, float]:
    """Lag-1 autocorrelation of a steering sequence and its mean absolute change.

    >>> a, c = steering_follow(np.array([0.0, 0.5, 1.0, 0.5, 0.0]))
    >>> round(a, 3), c
    (0.0, 0.5)
    """
    steer = np.asarray(steer, np.float64)
    if len(steer) < 3:
        return float("nan"), float("nan")
    x, y = steer[:-1], steer[1:]
    change = float(np.abs(y - x).mean())
    if x.std() == 0 or y.std() == 0:
        return float("nan"), change
    return float(np.corrcoef(x, y)[0, 1]), change


class MaskedSteering:
    """A policy that sees every frame with the steering indicator painted black."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def reset(self, env: Any = None, rng: Any = None) -> None:
        self.inner.reset(env, rng)

    def act(self, obs: np.ndarray, env: Any = None) -> np.ndarray:
        obs = np.array(obs, copy=True)
        obs[STEERING_INDICATOR] = 0
        return self.inner.act(obs, env)


@dataclass(frozen=True)
class Job:
    """One (cell, training seed), or the expert (``pre is None``)."""

    pre: PreprocessConfig | None
    seed: int
    demos: str
    episodes: int
    eval_seed: int
    batches: int
    eps: float
    channels: tuple[int, ...] | None = None
    """Conv channels of the network; ``None``: ``NetworkConfig``'s default."""

    @property
    def name(self) -> str:
        """The job's cache name: ``expert``, ``<cell>/seed<k>`` at the default budget and
        network, else with ``_b<batches>`` and ``_c<channels>`` appended."""
        if self.pre is None:
            return "expert"
        budget = "" if self.batches == TrainConfig().batches else f"_b{self.batches}"
        net = "" if self.channels is None else f"_c{channels_name(self.channels)}"
        return f"{cell_name(self.pre)}/seed{self.seed}{budget}{net}"

    def key(self) -> dict[str, Any]:
        """What the cached result must match to be reused (``channels`` only when set, so
        the default network's results keep their key)."""
        out = dataclasses.asdict(self)
        out["pre"] = None if self.pre is None else dataclasses.asdict(self.pre)
        if out["pre"] is not None and not out["pre"]["mask_steering"]:
            del out["pre"]["mask_steering"]  # the key results cached before the field had
        if self.channels is None:
            del out["channels"]
        else:
            out["channels"] = list(self.channels)
        return out


def channels_name(channels: Sequence[int]) -> str:
    """``16-32-32`` for ``(16, 32, 32)``."""
    return "-".join(map(str, channels))


def _episode_rows(
    policy: Any, env: Any, seeds: Sequence[int], limits: np.ndarray, eps: float
) -> list[dict[str, Any]]:
    from safe_bc.metrics import episode_metrics
    from safe_bc.rollout import run_episode

    rows = []
    for env_seed in seeds:
        ep = run_episode(
            env, policy, env_seed, np.random.default_rng(env_seed), keep_observations=False
        )
        base = env.unwrapped
        visited = base.tile_visited_count / len(base.track)
        m = episode_metrics(ep, tiles_visited=visited, thresholds=limits, eps=eps)
        autocorr, change = steering_follow(ep.actions[~ep.warmup, 0])
        rows.append({"env_seed": env_seed, **m, "steer_autocorr": autocorr, "steer_change": change})
    return rows


_DEMOS: dict[str, Any] = {}


def run_job(job: Job) -> pd.DataFrame:
    """Train the job's agent (or take the expert) and evaluate it on the selection tracks."""
    import torch

    from safe_bc.bc.policy import BCPolicy
    from safe_bc.collection import build_expert, stored_expert_config
    from safe_bc.data.store import load_demonstrations
    from safe_bc.envs import make_env
    from safe_bc.evaluation import EvalConfig
    from safe_bc.experiment import RunConfig, train_run
    from safe_bc.selection import SelectionConfig
    from safe_bc.tasks import dataset_action_bounds, task_defaults

    torch.set_num_threads(1)
    if job.demos not in _DEMOS:
        _DEMOS[job.demos] = load_demonstrations(Path(job.demos))
    demos = _DEMOS[job.demos]
    limits = demos.limits
    task = task_defaults("carracing")
    seeds = EvalConfig(episodes=job.episodes, seed=job.eval_seed, env=task.env).seeds()
    env = make_env(task.env)
    labels: dict[str, Any] = {"train_seed": job.seed}
    started = time.perf_counter()
    try:
        if job.pre is None:
            policies = {"full": build_expert(stored_expert_config(Path(job.demos)))}
            labels.update(
                cell="expert",
                crop_bar=np.nan,
                grayscale=np.nan,
                frame_stack=np.nan,
                final_loss=np.nan,
            )
        else:
            cfg = RunConfig(
                SelectionConfig(eps=job.eps, alpha=0.0),
                BCConfig(
                    preprocess=job.pre,
                    network=NetworkConfig(channels=job.channels or NetworkConfig().channels),
                    train=TrainConfig(batches=job.batches, seed=job.seed),
                ),
            )
            bounds = dataset_action_bounds(Path(job.demos))
            result, _ = train_run(demos, cfg, action_bounds=bounds)
            policy = BCPolicy(result.model, job.pre)
            policies = {"full": policy}
            if not (job.pre.crop_bar or job.pre.mask_steering):
                policies["steer_masked"] = MaskedSteering(policy)
            labels.update(
                cell=cell_name(job.pre),
                crop_bar=job.pre.crop_bar,
                grayscale=job.pre.grayscale,
                frame_stack=job.pre.frame_stack,
                final_loss=result.final_loss,
            )
        frames = []
        for view, policy in policies.items():
            rows = _episode_rows(policy, env, seeds, limits, job.eps)
            frames.append(pd.DataFrame(rows).assign(view=view, **labels))
    finally:
        env.close()
    out = pd.concat(frames, ignore_index=True)
    out["job_seconds"] = time.perf_counter() - started
    return out


def _cache_file(out: Path, job: Job) -> Path:
    return out / "runs" / f"{job.name}.parquet"


def _cached(out: Path, job: Job) -> pd.DataFrame | None:
    path = _cache_file(out, job)
    if not path.exists():
        return None
    frame, meta = read_table(path)
    if meta.get("job") != job.key():
        return None
    return frame.assign(job_revision=meta.get("git_revision", "unrecorded"))


def _run_and_store(args: tuple[Path, Job]) -> tuple[str, float]:
    out, job = args
    frame = run_job(job)
    write_table_atomic(_cache_file(out, job), frame, run_metadata(job=job.key()))
    return job.name, float(frame["job_seconds"].iloc[0])


def run_jobs(jobs: list[Job], out: Path, processes: int) -> pd.DataFrame:
    """Run the jobs not cached yet (side by side in ``processes`` spawned processes when > 1),
    then return every job's episodes."""
    missing = [j for j in jobs if _cached(out, j) is None]
    print(
        f"{len(jobs) - len(missing)} of {len(jobs)} jobs cached; running {len(missing)}", flush=True
    )
    started = time.perf_counter()
    work = [(out, j) for j in missing]
    if processes > 1 and len(missing) > 1:
        ctx = multiprocessing.get_context("spawn")  # a forked torch process can hang
        with ctx.Pool(min(processes, len(missing)), maxtasksperchild=4) as pool:
            for k, (name, secs) in enumerate(pool.imap_unordered(_run_and_store, work), 1):
                print(
                    f"[{k}/{len(missing)}] {name}: {secs:.0f} s "
                    f"({time.perf_counter() - started:.0f} s elapsed)",
                    flush=True,
                )
    else:
        for k, item in enumerate(work, 1):
            name, secs = _run_and_store(item)
            print(f"[{k}/{len(missing)}] {name}: {secs:.0f} s", flush=True)
    frames = []
    for j in jobs:
        frame = _cached(out, j)
        if frame is None:
            raise RuntimeError(f"job {j.name} has no cached result after running")
        channels = j.channels or NetworkConfig().channels
        frames.append(frame.assign(batches=j.batches, channels=channels_name(channels)))
    return pd.concat(frames, ignore_index=True)


def _variant_labels(episodes: pd.DataFrame, budgets: bool, nets: bool) -> pd.Series | None:
    """``b<batches>``, ``c<channels>`` or both per row, when a sweep varies them."""
    parts = []
    if budgets:
        parts.append("b" + episodes["batches"].astype(str))
    if nets:
        parts.append("c" + episodes["channels"].astype(str))
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else parts[0] + "_" + parts[1]


def summarise(episodes: pd.DataFrame, baseline: str) -> tuple[pd.DataFrame, ...]:
    """Per (cell, view): crossed means and CIs; paired differences of every cell to
    ``baseline`` (full view); the masked-minus-full difference per bar-kept cell."""
    from safe_bc.metrics import paired_crossed, summarize_crossed

    summary = summarize_crossed(episodes, ["cell", "view"], REPORT_METRICS)
    full = episodes[episodes["view"] == "full"]
    agents = full[full["cell"] != "expert"]
    paired = paired_crossed(
        agents, baseline, ["reward", "violation_steps", "any_violation"], by="cell"
    )
    copy_rows = []
    for cell, df in episodes[episodes["cell"] != "expert"].groupby("cell", sort=True):
        if "steer_masked" not in set(df["view"]):
            continue
        d = paired_crossed(df, "full", ["reward", "violation_steps", "steer_change"], by="view")
        copy_rows.append(d.assign(cell=cell))
    copycat = pd.concat(copy_rows, ignore_index=True) if copy_rows else pd.DataFrame()
    return summary, paired, copycat


def choose(summary: pd.DataFrame) -> str:
    """The default the measurement supports: among the agents' cells with the most training
    seeds (a screened cell with fewer seeds never decides), the fewest episodes beyond d_s,
    then the highest reward (the study maximises reward subject to safety)."""
    agents = summary[(summary["view"] == "full") & (summary["cell"] != "expert")]
    agents = agents[agents["n_train_seeds"] == agents["n_train_seeds"].max()]
    best = agents.sort_values(["any_violation", "reward"], ascending=[True, False])
    return str(best["cell"].iloc[0])


def _ci(row: pd.Series, m: str, digits: int = 1, prefix: str = "") -> str:
    mean, lo, hi = row[f"{prefix}{m}"], row[f"{prefix}{m}_lo"], row[f"{prefix}{m}_hi"]
    return f"{mean:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _paired_tab(paired: pd.DataFrame, reference: str) -> pd.DataFrame:
    if paired.empty:  # a single cell: nothing to pair
        return pd.DataFrame({"observation": [], f"reward - {reference}": []})
    d = paired.sort_values("d_reward", ascending=False)
    rows = list(d.iterrows())
    return pd.DataFrame(
        {
            "observation": d["cell"],
            f"reward - {reference}": [_ci(r, "reward", prefix="d_") for _, r in rows],
            "steps beyond d_s": [_ci(r, "violation_steps", prefix="d_") for _, r in rows],
            "share of episodes beyond d_s": [
                _ci(r, "any_violation", 2, prefix="d_") for _, r in rows
            ],
            "seeds better": [f"{r.seeds_better}/{r.n_seeds_paired}" for r in d.itertuples()],
        }
    )


def markdown(
    summary: pd.DataFrame,
    paired: pd.DataFrame,
    paired_chosen: pd.DataFrame,
    copycat: pd.DataFrame,
    episodes: pd.DataFrame,
    meta: dict[str, Any],
    baseline: str,
    chosen: str,
    title: str,
) -> str:
    full = summary[summary["view"] == "full"].sort_values("reward", ascending=False)
    counts = (
        episodes[episodes["view"] == "full"]
        .groupby("cell")["any_violation"]
        .agg(lambda s: f"{int(s.sum())}/{len(s)}")
    )
    loss = episodes[episodes["view"] == "full"].groupby("cell")["final_loss"].mean()
    table = pd.DataFrame(
        {
            "observation": full["cell"],
            "seeds x tracks": [f"{r.n_train_seeds} x {r.n_tracks}" for r in full.itertuples()],
            "reward": [_ci(r, "reward") for _, r in full.iterrows()],
            "episodes beyond d_s": [counts[c] for c in full["cell"]],
            "steps beyond d_s / episode": [_ci(r, "violation_steps") for _, r in full.iterrows()],
            "off-road steps / episode": [_ci(r, "offroad_steps") for _, r in full.iterrows()],
            "safety mean (px)": [_ci(r, "safety_mean", 2) for _, r in full.iterrows()],
            "final loss": [
                f"{loss[c]:.4f}" if c in loss and np.isfinite(loss[c]) else "" for c in full["cell"]
            ],
        }
    )
    diff, diff_chosen = _paired_tab(paired, baseline), _paired_tab(paired_chosen, chosen)
    follow = summary[summary["view"].isin(["full", "steer_masked"])]
    if len(copycat):  # with masked runs, the cells that have them; else every cell
        follow = follow[follow["cell"].isin(set(copycat["cell"]) | {"expert"})]
    follow_tab = pd.DataFrame(
        {
            "observation": follow["cell"],
            "view": follow["view"],
            "steering lag-1 autocorrelation": [
                _ci(r, "steer_autocorr", 3) for _, r in follow.iterrows()
            ],
            "mean |steering change|": [_ci(r, "steer_change", 3) for _, r in follow.iterrows()],
        }
    )
    mask_tab = (
        pd.DataFrame(
            {
                "observation": copycat["cell"],
                "reward, masked - full": [
                    _ci(r, "reward", prefix="d_") for _, r in copycat.iterrows()
                ],
                "steps beyond d_s, masked - full": [
                    _ci(r, "violation_steps", prefix="d_") for _, r in copycat.iterrows()
                ],
            }
        )
        if len(copycat)
        else pd.DataFrame()
    )
    lines = [
        f"# {title}",
        "",
        f"Plain behaviour cloning (alpha 0, conv channels "
        f"{' / '.join(meta.get('channels') or [channels_name(NetworkConfig().channels)])}, "
        f"{' / '.join(map(str, meta['batches']))} batches of 64) "
        f"on the default demonstrations, {len(meta['seeds'])} training seeds "
        f"({', '.join(map(str, meta['seeds']))}) x {meta['episodes']} selection tracks "
        f"(held-out seed block {meta['eval_seed']}, used by no final table); the expert on "
        "the same tracks. Means with 95% crossed-bootstrap intervals (seeds x tracks). "
        f"Default chosen from this table: **{chosen}** (among the cells with every training "
        "seed: fewest episodes beyond d_s, then highest reward)."
        + (
            f" Cells with {len(meta['screen_seeds'])} seed(s) "
            f"({', '.join(map(str, meta['screen_seeds']))}) are a screen: they are reported "
            "but do not decide."
            if meta.get("screen_cells")
            else ""
        ),
        "",
        table.to_markdown(index=False),
        "",
        f"## Paired differences to `{baseline}`, same seeds x tracks",
        "",
        diff.to_markdown(index=False),
        "",
        *(
            [
                f"## Paired differences to the chosen `{chosen}`, same seeds x tracks",
                "",
                diff_chosen.to_markdown(index=False),
                "",
            ]
            if chosen != baseline
            else []
        ),
        "## Copycat check: does the agent copy its steering from the indicator?",
        "",
        "Each bar-kept agent again on the same tracks with the steering indicator painted "
        "black (`view = steer_masked`); differences masked - full on the same seeds x tracks:",
        "",
        mask_tab.to_markdown(index=False)
        if len(mask_tab)
        else "(not run here: no cell was evaluated with the indicator masked)",
        "",
        "How much steering follows itself (scored steps of every episode):",
        "",
        follow_tab.to_markdown(index=False),
        "",
        f"Code {meta['git_revision']}; command `{meta['command']}`; d_s from the "
        f"demonstrations, eps {meta['eps']} px; created {meta['created_utc']} on "
        f"{meta['cpus']} CPUs. Episodes per job revision (each job cached in `runs/` with "
        f"the revision that ran it; 'unrecorded': jobs cached before revisions were "
        f"recorded): {meta['job_revisions']}.",
        "",
    ]
    return "\n".join(lines)


def plot(summary: pd.DataFrame, expert: pd.Series | None, path: Path, title: str) -> Path:
    import matplotlib.pyplot as plt

    from safe_bc.plots import save_figure

    full = summary[(summary["view"] == "full") & (summary["cell"] != "expert")]
    full = full.sort_values("reward")
    masked = summary[summary["view"] == "steer_masked"].set_index("cell")
    y = np.arange(len(full))
    fig, axes = plt.subplots(1, 2, figsize=(11, 0.45 * len(full) + 1.5), sharey=True)
    decides = (full["n_train_seeds"] == full["n_train_seeds"].max()).to_numpy()
    for ax, m, panel in (
        (axes[0], "reward", "reward"),
        (axes[1], "any_violation", "share of episodes beyond d_s"),
    ):
        err = np.vstack([full[m] - full[f"{m}_lo"], full[f"{m}_hi"] - full[m]])
        for keep, style, label in ((decides, "o", "all seeds"), (~decides, "s", "screen (1 seed)")):
            if keep.any():
                ax.errorbar(full[m][keep], y[keep], xerr=err[:, keep], fmt=style,
                            color="tab:blue", mfc="tab:blue" if style == "o" else "white",
                            label=f"full frame, {label}")  # fmt: skip
        mk = full["cell"].map(lambda c, m=m: masked[m].get(c, np.nan) if len(masked) else np.nan)
        ax.plot(mk, y, "x", color="tab:red", label="steering indicator masked")
        if expert is not None:
            ax.axvline(expert[m], color="k", ls="--", lw=1, label="expert")
        ax.set_title(panel)
        ax.grid(alpha=0.3)
    axes[0].set_yticks(y, full["cell"])
    axes[0].legend(loc="lower right", fontsize=8)
    fig.suptitle(f"{title}: seeds x selection tracks, 95% crossed CIs")
    return save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds")
    p.add_argument("--episodes", type=int, default=20, help="selection tracks per agent")
    p.add_argument(
        "--eval-seed",
        type=int,
        default=SELECTION_EVAL_SEED,
        help="held-out seed block (selection tracks)",
    )
    p.add_argument(
        "--batches",
        type=int,
        nargs="+",
        default=[TrainConfig().batches],
        help="BC batches (several: a training-budget sweep, cells named cell@b<batches>)",
    )
    p.add_argument(
        "--channels",
        nargs="+",
        default=None,
        help="conv channels as 16-32-32 (several: a network sweep, cells named cell@c<channels>)",
    )
    p.add_argument("--name", default="observation", help="stem of the Markdown and figure files")
    p.add_argument("--title", default="Observation ablation (CarRacing, plain BC)")
    p.add_argument(
        "--cells", nargs="+", default=None, help="cells run with every --seeds (default: all 18)"
    )
    p.add_argument(
        "--screen-cells",
        nargs="+",
        default=[],
        help="cells run with --screen-seeds only ('all': all 18); a screen never decides",
    )
    p.add_argument("--screen-seeds", type=int, nargs="+", default=[0])
    p.add_argument("--baseline", default="nobar_grey_k1", help="cell the others are paired with")
    p.add_argument("--demos", type=Path, default=Path("data/demos"))
    p.add_argument("--processes", type=int, default=1, help="> 1: spawned local processes")
    p.add_argument("--out", type=Path, default=Path("results/ablation/observation"))
    args = p.parse_args(argv)

    from safe_bc.tasks import task_defaults

    cells = all_cells()
    known = {cell_name(c): c for c in cells}
    if args.screen_cells == ["all"]:
        args.screen_cells = list(known)
    unknown = sorted((set(args.cells or []) | set(args.screen_cells)) - set(known))
    if unknown:
        p.error(f"unknown cells {unknown}; known: {sorted(known)}")
    if args.cells:
        cells = [known[c] for c in args.cells]
    screen = [known[c] for c in args.screen_cells]
    if not (args.demos / "dataset.json").exists():
        p.error(f"no demonstrations at {args.demos} (make demos)")
    eps = task_defaults("carracing").eps
    common = dict(demos=str(args.demos), episodes=args.episodes, eval_seed=args.eval_seed, eps=eps)
    jobs = [Job(None, 0, batches=TrainConfig().batches, **common)]
    try:
        nets = (
            [None]
            if args.channels is None
            else [tuple(int(c) for c in spec.split("-")) for spec in args.channels]
        )
        for net in nets:
            NetworkConfig(channels=net or NetworkConfig().channels)
        # the default network is the default's job (cached without a channels key)
        nets = [None if net == NetworkConfig().channels else net for net in nets]
    except ValueError as e:
        p.error(f"--channels: {e}")
    plan = [(s, c) for s in args.seeds for c in cells]
    plan += [(s, c) for s in args.screen_seeds for c in screen if (s, c) not in plan]
    plan.sort(key=lambda sc: sc[0])  # every cell gets its first seed before any its second
    jobs += [
        Job(c, s, batches=b, channels=n, **common)
        for s, c in plan
        for b in args.batches
        for n in nets
    ]
    args.out.mkdir(parents=True, exist_ok=True)
    episodes = run_jobs(jobs, args.out, args.processes)
    variant = _variant_labels(episodes, len(args.batches) > 1, len(nets) > 1)
    if variant is not None:  # a budget or network sweep: one row per cell and variant
        agent = episodes["cell"] != "expert"
        episodes.loc[agent, "cell"] = episodes.loc[agent, "cell"] + "@" + variant[agent]
        if "@" not in args.baseline:  # the first cell at the default budget and network
            first = episodes[agent & (episodes["cell"].str.startswith(cell_name(cells[0]) + "@"))]
            default = first[
                (first["batches"] == TrainConfig().batches)
                & (first["channels"] == channels_name(NetworkConfig().channels))
            ]
            args.baseline = str((default if len(default) else first)["cell"].iloc[0])
    if args.baseline not in set(episodes["cell"]):
        p.error(f"--baseline {args.baseline} is not among the cells run")
    baseline = args.baseline
    summary, paired, copycat = summarise(episodes, baseline)
    chosen = choose(summary)
    agents = episodes[(episodes["view"] == "full") & (episodes["cell"] != "expert")]
    paired_chosen = paired_crossed(
        agents, chosen, ["reward", "violation_steps", "any_violation"], by="cell"
    )
    meta = run_metadata(
        seeds=args.seeds,
        episodes=args.episodes,
        eval_seed=args.eval_seed,
        batches=args.batches,
        channels=args.channels,
        eps=eps,
        demos=str(args.demos),
        cells=[cell_name(c) for c in cells],
        screen_cells=args.screen_cells,
        screen_seeds=args.screen_seeds,
        baseline=baseline,
        chosen=chosen,
        bootstrap_seed=0,
        job_revisions=episodes["job_revision"].value_counts().to_dict(),
    )
    for name, frame in (
        ("episodes", episodes),
        ("summary", summary),
        ("paired", paired),
        ("copycat", copycat),
        ("paired_chosen", paired_chosen),
    ):
        write_table_atomic(args.out / f"{name}.parquet", frame, meta)
    text = markdown(
        summary, paired, paired_chosen, copycat, episodes, meta, baseline, chosen, args.title
    )
    write_text_atomic(args.out / f"{args.name}.md", text)
    exp = summary[summary["cell"] == "expert"]
    plot(summary, exp.iloc[0] if len(exp) else None, args.out / f"{args.name}.png", args.title)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
