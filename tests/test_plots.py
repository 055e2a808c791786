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
            if line.get_label().endswith("at d_s"):
                seen.append((line.get_label(), float(line.get_ydata()[0])))
        return real_save(fig, *args, **kwargs)

    monkeypatch.setattr(plt.Figure, "savefig", grab)
    plot_traces(traces, {"p": {"method": "agent"}}, tmp_path / "t.png",
                limits={"left": 2.85, "right": 2.87})  # fmt: skip
    assert seen == [("left at d_s", 2.85), ("right at d_s", 2.87)]
    seen.clear()
    plot_traces(traces, {"p": {"method": "agent"}}, tmp_path / "u.png")  # no limits: no lines
    assert seen == []


def test_the_distance_at_d_s_is_the_closest_scored_approach() -> None:
    from safe_bc.distributed.compare import limit_distances

    demos = SimpleNamespace(
        safety=np.array([[3.0, 9.0], [1.0, 8.0], [4.0, 2.5]]),
        scored=np.array([True, False, True]),
        safety_dims=("left", "right"),
    )
    assert limit_distances(demos) == {"left": 3.0, "right": 2.5}
