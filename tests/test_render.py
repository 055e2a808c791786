"""Pictures: annotated episode videos (MP4/GIF) and the track map of driven paths."""

from __future__ import annotations

from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest

from safe_bc.render import (
    HEADER,
    CriticalZone,
    annotated_frames,
    dim_states,
    draw_paths,
    frame_state,
    record,
    render_episode,
)
from safe_bc.rollout.collect import build_expert
from safe_bc.tasks.carracing.expert import ExpertConfig

STEPS = 60


@pytest.fixture(scope="module")
def expert_trace():
    return record(build_expert(ExpertConfig()), 3, label="expert", max_steps=STEPS)


def test_mp4_of_a_60_step_expert_episode(tmp_path: Path) -> None:
    zone = CriticalZone(np.array([40.0, 60.0, 40.0]), eps=2.0)
    out = tmp_path / "episode.mp4"
    trace = render_episode(
        build_expert(ExpertConfig()), 3, out, label="expert", zone=zone, max_steps=STEPS
    )
    assert len(trace.episode) == STEPS and trace.positions.shape == (STEPS, 2)
    reader = imageio.get_reader(out)
    try:
        assert reader.count_frames() == STEPS
        meta = reader.get_meta_data()
        assert meta["size"] == (96 * 4, HEADER + 96 * 4) and meta["fps"] == 50
    finally:
        reader.close()


def test_gif_frames_and_overlay(expert_trace, tmp_path: Path) -> None:
    from safe_bc.render import write_video

    frames = annotated_frames(expert_trace, None, scale=2)
    assert len(frames) == STEPS and frames[0].shape == (HEADER + 192, 192, 3)
    out = write_video(frames, tmp_path / "episode.gif")
    assert len(imageio.mimread(out, memtest=False)) == STEPS
    # the rays are drawn: the upscaled frame differs from the plain upscaled observation
    plain = np.repeat(np.repeat(expert_trace.episode.observations[-1], 2, 0), 2, 1)
    assert (frames[-1][HEADER:] != plain).any(axis=-1).sum() > 20


def test_states_follow_the_critical_zone(expert_trace) -> None:
    ep = expert_trace.episode
    assert (dim_states(ep, None)[~ep.warmup] == "").all()
    assert (dim_states(ep, None)[ep.warmup] == "warmup").all()
    # limits at the worst cost seen: nothing beyond, the worst step of each dim critical
    scored = ~ep.warmup
    worst = ep.costs[scored].max(axis=0).astype(np.float64)
    states = dim_states(ep, CriticalZone(worst, eps=0.0))
    assert not (states == "violation").any()
    assert (states[scored] == "critical").any(axis=0).all()
    tight = dim_states(ep, CriticalZone(worst - 1.0, eps=0.5))
    assert (tight == "violation").any()
    assert frame_state(np.array(["safe", "critical", "safe"], object)) == "critical"
    assert frame_state(np.array(["safe", "critical", "safe"], object), "all") == "safe"
    assert frame_state(np.array(["violation", "safe", "safe"], object), "all") == "violation"
    assert frame_state(np.array(["warmup"] * 3, object)) == "warmup"


def test_paths_png(expert_trace, tmp_path: Path) -> None:
    import dataclasses

    other = dataclasses.replace(expert_trace, label="agent")
    out = draw_paths([expert_trace, other], tmp_path / "paths.png", zone=None)
    image = imageio.imread(out)
    assert image.shape[1] > image.shape[0] > 200  # two panels side by side


def test_cli_render_expert_gif(tmp_path: Path, monkeypatch, capsys) -> None:
    from safe_bc.cli.commands import main

    monkeypatch.chdir(tmp_path)  # no data/demos here: rays without critical-zone states
    code = main(["render", "--expert", "--seed", "3", "--out", "e.gif", "--max-steps", "30"])
    assert code == 0, capsys.readouterr().err
    assert "30 frames of the expert" in capsys.readouterr().out
    assert len(imageio.mimread(tmp_path / "e.gif", memtest=False)) == 30
    assert main(["render", "--seed", "3", "--out", "x.mp4"]) == 2
    assert "--checkpoint" in capsys.readouterr().err


def test_a_task_without_a_drawing_cannot_be_rendered(rehab_demos, tmp_path: Path, capsys) -> None:
    from safe_bc.cli.commands import main
    from safe_bc.render import drawing_of
    from safe_bc.tasks import task_defaults

    with pytest.raises(ValueError, match="'rehab' cannot be rendered"):
        drawing_of(task_defaults("rehab"))
    argv = ["render", "--expert", "--demos", str(rehab_demos), "--out", str(tmp_path / "r.gif")]
    assert main(argv) == 2
    assert "cannot be rendered" in capsys.readouterr().err
    assert not (tmp_path / "r.gif").exists()
