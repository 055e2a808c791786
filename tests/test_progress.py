"""Progress bars: drawn on a terminal, quiet off one and when asked; `safe-bc render` draws its
steps, frames and encoding."""

from __future__ import annotations

import io
from pathlib import Path

from safe_bc.progress import progress_bar


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_bar_shows_on_a_terminal_only_and_not_when_asked() -> None:
    for file, show, drawn in [(Terminal(), True, True), (io.StringIO(), True, False),
                              (Terminal(), False, False)]:  # fmt: skip
        with progress_bar(show=show, total=3, desc="work", file=file) as bar:
            bar.update(3)
        assert ("work" in file.getvalue()) == drawn


def test_a_log_gets_plain_lines_as_time_passes_and_no_carriage_returns(monkeypatch) -> None:
    """Off a terminal: a line per PLAIN_EVERY seconds of work, one at its end, no bar."""
    import safe_bc.progress as progress

    clock = iter([0.0, 10.0, 31.0, 40.0, 65.0, 70.0])
    monkeypatch.setattr(progress.time, "monotonic", lambda: next(clock))
    log = io.StringIO()
    bar = progress_bar(total=4, desc="collect", unit="ep", file=log)  # start: 0 s
    for _ in range(4):  # at 10, 31 (a line), 40, 65 (a line) s
        bar.update()
    bar.set_postfix(steps=12)
    bar.close()  # at 70 s: the last line
    lines = log.getvalue().splitlines()
    assert "\r" not in log.getvalue()
    assert lines == [
        "collect: 2/4 ep (50%), 31 s",
        "collect: 4/4 ep (100%), 65 s",
        "collect: 4/4 ep (100%), 70 s, steps=12",
    ]


def test_render_draws_its_progress_on_a_terminal(tmp_path: Path, monkeypatch) -> None:
    import sys

    from safe_bc.render import render_episode
    from safe_bc.rollout.collect import build_expert
    from safe_bc.tasks.carracing.expert import ExpertConfig

    err = Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    out = tmp_path / "episode.mp4"
    render_episode(build_expert(ExpertConfig()), 3, out, max_steps=20, progress=True)
    text = err.getvalue()
    assert "episode" in text and "20/20" in text and "frames" in text and "encode" in text
    err.truncate(0)
    render_episode(build_expert(ExpertConfig()), 3, out, max_steps=20, progress=False)
    assert err.getvalue() == ""
