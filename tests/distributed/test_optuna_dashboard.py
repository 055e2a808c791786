"""optuna-dashboard reads the study's Optuna copy right: a real headless Chromium renders the
study page of a study written by the searcher's own export, and the page shows the objective's
name and the infeasible trial as infeasible.

Skipped where optuna-dashboard (the dev extra) or a Chromium binary (optional: Debian's
``apt-get install chromium``) is missing.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import threading
from pathlib import Path

import pytest

pytest.importorskip("optuna_dashboard")
CHROMIUM = next(
    (p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None
)
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary")


def _study(url: str) -> None:
    """Two trials through ConstrainedOptunaSearch's export: the infeasible one has the higher
    objective (like trial 1 of the default study)."""
    from optuna.samplers import TPESampler

    from safe_bc.study.search import ConstrainedOptunaSearch, SpaceSampler
    from safe_bc.study.spec import Float

    s = ConstrainedOptunaSearch(
        space=SpaceSampler({"a": Float(0.0, 1.0)}),
        metric="reward_lcb",
        mode="max",
        sampler=TPESampler(seed=0),
        export_to=url,
    )
    results = [(906.8, -0.1, 0.54), (902.3, -0.25, -0.06)]
    for n, (value, safety, violation) in enumerate(results):
        s.suggest(f"t{n}")
        s.on_trial_complete(f"t{n}", {"reward_lcb": value, "constraint_safety": safety,
                                      "constraint_violation": violation,
                                      "constraint_deferral": -1.0})  # fmt: skip


def _text(dom: str) -> str:
    dom = re.sub(r"<(script|style)[^>]*>.*?</\1>", " ", dom, flags=re.S)
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", dom))


@pytest.mark.timeout(180)
def test_dashboard_shows_objective_name_and_infeasible_trial(tmp_path: Path) -> None:
    from wsgiref.simple_server import WSGIRequestHandler, make_server

    import optuna
    from optuna_dashboard import wsgi

    url = f"sqlite:///{tmp_path / 'optuna.db'}"
    _study(url)
    study = optuna.load_study(study_name="optuna", storage=url)
    assert study.best_trial.number == 1  # Optuna's best_trial: feasible trials only

    class Quiet(WSGIRequestHandler):
        def log_message(self, *args: object) -> None:
            pass

    server = make_server("127.0.0.1", 0, wsgi(url), handler_class=Quiet)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        page = f"http://127.0.0.1:{server.server_port}/dashboard/studies/1"
        flags = [
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            f"--user-data-dir={tmp_path / 'chromium'}",
            "--virtual-time-budget=10000",
        ]
        proc = subprocess.run(
            [CHROMIUM, *flags, "--dump-dom", page], capture_output=True, text=True, timeout=150
        )
    finally:
        server.shutdown()
        thread.join()
    text = _text(proc.stdout)
    assert "History" in text, proc.stderr[-2000:]  # the page rendered
    assert "reward_lcb" in text and "Objective 0" not in text  # the objective's name
    assert "Infeasible" in text  # the timeline marks trial 0 infeasible (its list constraint)
    # the dashboard's own "Best Trial" still ignores feasibility (storage.get_best_trial)
    assert "Best Trial (number=0)" in text
