"""Figures read by a person: the traces show where d_s lies in each dimension."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd


def test_traces_draw_each_dimensions_distance_at_d_s(tmp_path, monkeypatch) -> None:
    import matplotlib.pyplot as plt

    from safe_bc.plots import plot_traces

    steps = np.arange(20)
    traces = pd.DataFrame(
        {"policy": "p", "env_seed": 7, "step": steps, "warmup": False, "offroad": False,
         "safety_left": 5.0 + np.sin(steps), "safety_right": 6.0 - np.sin(steps)}
    )  # fmt: skip
    seen: list[tuple[str, float]] = []
    real_save = plt.Figure.savefig

    def grab(fig, *args, **kwargs):
        for line in fig.axes[0].get_lines():
            if " at d_s" in line.get_label():
                seen.append((line.get_label().split(" (")[0], float(line.get_ydata()[0])))
        return real_save(fig, *args, **kwargs)

    monkeypatch.setattr(plt.Figure, "savefig", grab)
    plot_traces(traces, {"p": {"method": "agent"}}, tmp_path / "t.png",
                limits={"left": 2.85, "right": 2.87})  # fmt: skip
    assert seen == [("left at d_s", 2.85), ("right at d_s", 2.87)]
    seen.clear()
    plot_traces(traces, {"p": {"method": "agent"}}, tmp_path / "u.png")  # no limits: no lines
    assert seen == []


def test_the_distance_at_d_s_is_the_closest_scored_approach() -> None:
    from safe_bc.compare.run import limit_distances

    demos = SimpleNamespace(
        safety=np.array([[3.0, 9.0], [1.0, 8.0], [4.0, 2.5]]),
        scored=np.array([True, False, True]),
        safety_dims=("left", "right"),
    )
    assert limit_distances(demos) == {"left": 3.0, "right": 2.5}


# --- what a person reads on each figure: units, d_s, seeds x episodes, no text on text ---


def _drawn(monkeypatch) -> list:
    """The figures saved from here on, each with ``overlaps``: the pairs of its texts whose
    boxes overlap as saved (:func:`_overlapping_text`)."""
    import matplotlib.pyplot as plt

    figures: list = []
    real_save = plt.Figure.savefig

    def grab(fig, *args, **kwargs):
        out = real_save(fig, *args, **kwargs)
        fig.overlaps = _overlapping_text(fig)  # while it is open: closing drops its renderer
        figures.append(fig)
        return out

    monkeypatch.setattr(plt.Figure, "savefig", grab)
    return figures


def _shown_ticks(axis, lo_hi) -> list:
    lo, hi = sorted(lo_hi)
    labels = axis.get_ticklabels()
    return [t for t, v in zip(labels, axis.get_ticklocs(), strict=False) if lo <= v <= hi]


def _overlapping_text(fig) -> list[tuple[str, str]]:
    """Pairs of texts whose boxes overlap: the figure's titles, each panel's title, axis
    labels and shown tick labels (legends and annotations aside)."""
    import itertools

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    texts = [*fig.texts, fig._suptitle]
    for ax in fig.axes:
        texts += [ax.title, ax.xaxis.label, ax.yaxis.label]
        texts += _shown_ticks(ax.xaxis, ax.get_xlim()) + _shown_ticks(ax.yaxis, ax.get_ylim())
    shown = {id(t): t for t in texts if t is not None and t.get_visible() and t.get_text().strip()}
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in shown.values()]
    return [(a, b) for (a, ba), (b, bb) in itertools.combinations(boxes, 2) if ba.overlaps(bb)]


def test_histograms_name_the_unit_draw_a_labelled_d_s_and_count_the_episodes(
    tmp_path, monkeypatch
) -> None:
    from safe_bc.data.demos import Demonstrations
    from safe_bc.plots import plot_cost_histograms

    figures = _drawn(monkeypatch)
    rng = np.random.default_rng(0)
    n = 300
    safety = rng.uniform(3.0, 12.0, (n, 3)).astype(np.float32)
    demos = Demonstrations(
        observations=np.zeros((n, 2), np.float32), actions=np.zeros((n, 2), np.float32),
        costs=(45.0 - safety).astype(np.float32), safety=safety,
        episode_ids=np.repeat(np.arange(3), n // 3), steps=np.tile(np.arange(n // 3), 3),
        seeds=np.repeat(np.arange(3), n // 3), warmup=np.zeros(n, bool),
        safety_dims=("left", "front", "right"),
    )  # fmt: skip
    plot_cost_histograms(demos, tmp_path / "h.png", eps=2.0, title="data/demos", units=("px",) * 3)
    (fig,) = figures
    assert [ax.get_xlabel() for ax in fig.axes] == [
        f"{d}: distance (px), higher is safer" for d in ("left", "front", "right")
    ]
    lows = safety.min(axis=0)
    for ax, lo in zip(fig.axes, lows, strict=True):
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        assert f"at d_s: {lo:.3g} px" in legend
        assert any(float(line.get_xdata()[0]) == lo for line in ax.get_lines())
    assert "3 demonstration episodes" in fig._suptitle.get_text()
    assert fig.overlaps == []


def test_the_alpha_sweep_says_seeds_x_episodes_from_its_table_and_names_units(
    tmp_path, monkeypatch
) -> None:
    from safe_bc.plots import plot_alpha_sweep

    figures = _drawn(monkeypatch)
    rows = []
    for alpha in (0.0, 0.5, 1.0):
        rows.append({"method": f"alpha={alpha:g}", "alpha": alpha, "rest": "all",
                     "n_train_seeds": 11, "n_tracks": 10})  # fmt: skip
    rows.append({"method": "expert", "alpha": np.nan, "rest": "", "n_train_seeds": 1,
                 "n_tracks": 10})  # fmt: skip
    table = pd.DataFrame(rows)
    for m in ("reward", "safety_mean"):
        table[m], table[f"{m}_lo"], table[f"{m}_hi"] = 5.0, 4.0, 6.0
    plot_alpha_sweep(table, tmp_path / "a.png", units=("px",) * 3)
    rehab = ("HRR fraction", "model units", "100 mmHg")
    plot_alpha_sweep(table.assign(n_train_seeds=8, n_tracks=50), tmp_path / "b.png", units=rehab)
    car, clinic = figures
    assert car._suptitle.get_text() == (
        "mean and 95% CI over 11 training seeds x 10 held-out episodes (expert: 10 episodes)"
    )
    assert car.axes[1].get_ylabel() == "safety mean (px, higher is safer)"
    assert "8 training seeds x 50 held-out episodes" in clinic._suptitle.get_text()
    assert "100 mmHg" in clinic.axes[1].get_title()
    assert car.overlaps == [] and clinic.overlaps == []


def test_traces_name_units_and_keep_titles_off_the_ticks(tmp_path, monkeypatch) -> None:
    from safe_bc.plots import plot_traces

    figures = _drawn(monkeypatch)
    steps = np.arange(200)
    traces = pd.concat(
        pd.DataFrame(
            {
                "policy": p,
                "env_seed": 7,
                "step": steps,
                "warmup": False,
                "offroad": False,
                "safety_left": 5.0 + np.sin(steps / 9),
                "safety_right": 60.0 - np.sin(steps / 7),
            }
        )
        for p in ("alpha=0 seed=0", "alpha=0.8 seed=0", "expert")
    )
    labels = {"alpha=0 seed=0": {"method": "alpha=0"}, "expert": {"method": "expert"}}
    plot_traces(traces, labels, tmp_path / "t.png", limits={"left": 2.85, "right": 20.0},
                units={"left": "px", "right": "px"})  # fmt: skip
    (fig,) = figures
    assert {ax.get_ylabel() for ax in fig.axes} == {"distance (px)"}
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert legend == ["left (px)", "left at d_s (2.85 px)", "right (px)", "right at d_s (20 px)"]
    assert fig.axes[0].get_title() == "alpha=0 seed=0, episode seed 7"  # the key, with its seed
    assert fig.overlaps == []


def _trials(n: int = 12) -> pd.DataFrame:
    rng = np.random.default_rng(1)
    return pd.DataFrame(
        {
            "trial_id": [f"t{i:07d}" for i in range(n)],
            "reward_lcb": np.r_[[902.5, 901.5, 900.7, 902.0], rng.uniform(-50, 890, n - 4)],
            "safety_mean": np.r_[[7.26, 7.30, 7.35, 7.257], rng.uniform(5.8, 7.3, n - 4)],
            "feasible": [True, True, True, False] + [bool(i % 2) for i in range(n - 4)],
            "train_seeds": 1,
            "episodes": [15] * (n - 3) + [3] * 3,
            "status": ["done"] * (n - 3) + ["stopped"] * 3,
        }
    )


def test_pareto_names_its_objective_and_sets_the_winner_apart(tmp_path, monkeypatch) -> None:
    from safe_bc.plots import plot_pareto

    figures = _drawn(monkeypatch)
    trials = _trials()
    plot_pareto(
        trials, 6.95, tmp_path / "p.png", winner="t0000000",
        candidates=["t0000000", "t0000001", "t0000002"], title="default: 12/12 trials",
        objective="reward_lcb", safety_label="safety mean (px to the grass; higher is safer)",
    )  # fmt: skip
    (fig,) = figures
    full, zoom = fig.axes
    assert full.get_ylabel().startswith("reward_lcb")
    # the zoom spans the candidates, a few reward points, not the whole study
    assert zoom.get_ylim()[1] - zoom.get_ylim()[0] < 5
    named = {t.get_text() for t in zoom.texts}
    assert {"t0000000", "t0000001", "t0000002", "t0000003"} <= named
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "winner t0000000" in legend and "final-phase candidates (3)" in legend
    assert fig._suptitle.get_text().splitlines()[1] == (
        "9 trials of 1 training seed x 15 episodes; "
        "3 trials of 1 training seed x 3 episodes (stopped early)"
    )
    assert fig.overlaps == []


def test_the_pareto_script_draws_a_study_folder_again(tmp_path) -> None:
    import json

    from safe_bc.data.store import write_table_atomic
    from scripts.pareto_figure import draw

    trials = _trials()
    meta = {"threshold": 6.95, "objective": "reward_lcb",
            "study": {"name": "s", "trials": 12, "env": {"env_id": "CarRacing-v3"}}}  # fmt: skip
    write_table_atomic(tmp_path / "trials.parquet", trials, meta)
    final = pd.DataFrame({"method": ["t0000000", "t0000001", "expert"],
                          "role": ["candidate", "candidate", "expert"]})  # fmt: skip
    write_table_atomic(tmp_path / "final.parquet", final, {})
    (tmp_path / "best.json").write_text(json.dumps({"trial_id": "t0000001", "feasible": True}))
    path = draw(tmp_path)
    assert path == tmp_path / "pareto.png" and path.read_bytes()[:4] == b"\x89PNG"
