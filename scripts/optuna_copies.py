"""Rewrite every committed study's Optuna copy (``results/**/optuna.db``) as a study writes it
today, from the study's own committed tables: the objective's metric name (``trials.parquet``'s
``objective``), the trials the screening stopped stored PRUNED (their ``status`` is
``stopped``), the final phase's winner marked (``best.json``), the named constraints also in
the list form optuna-dashboard reads. Parameters, values and constraints are the copy's own.
``python -m scripts.optuna_copies`` (prints one line per copy)."""

from __future__ import annotations

import copy
import json
import warnings
from pathlib import Path

from safe_bc.data.store import read_table
from safe_bc.distributed.search import STOPPED, WINNER, export_study
from safe_bc.study import CONSTRAINTS

ROOT = Path(__file__).resolve().parents[1]


def rewrite(folder: Path) -> str:
    """Rewrite ``folder/optuna.db`` from ``folder``'s ``trials.parquet`` and ``best.json``."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    url = f"sqlite:///{folder / 'optuna.db'}"
    (name,) = optuna.study.get_all_study_names(url)
    stored = optuna.load_study(study_name=name, storage=url)
    trials, meta = read_table(folder / "trials.parquet")
    stopped = set(trials.loc[trials["status"] == "stopped", "trial_id"])
    best = (
        json.loads((folder / "best.json").read_text()) if (folder / "best.json").is_file() else {}
    )
    winner = best.get("trial_id")  # marked feasible or not, as the study marks it
    study = optuna.create_study(study_name=name, directions=stored.directions)
    marked = []
    for t in stored.trials:
        t = copy.copy(t)
        if t.user_attrs.get("tune_trial_id") in stopped:
            t.user_attrs = {**t.user_attrs, STOPPED: True}
        marked.append(t)
    study.add_trials(marked)
    ids = {t.user_attrs.get("tune_trial_id"): t.number for t in study.trials}
    attrs = {**stored.user_attrs, WINNER: winner, "final_winner_number": ids.get(winner),
             "final_winner_feasible": bool(best.get("feasible"))}  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        export_study(study, url, attrs, metric=meta.get("objective", "reward_mean"),
                     constraint_names=tuple(CONSTRAINTS), winner=winner)  # fmt: skip
    again = optuna.load_study(study_name=name, storage=url)
    pruned = sum(t.state.name == "PRUNED" for t in again.trials)
    return (
        f"{folder.relative_to(ROOT)}: {len(again.trials)} trials, {pruned} pruned, metric "
        f"{again.metric_names}, winner {winner}"
    )


def main() -> None:
    for db in sorted((ROOT / "results").rglob("optuna.db")):
        if (db.parent / "trials.parquet").is_file():
            print(rewrite(db.parent))


if __name__ == "__main__":
    main()
