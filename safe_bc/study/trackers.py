"""Experiment trackers for a study: ``safe-bc tune --tracker wandb|mlflow`` hands Ray Tune's own
integrations (``ray.air.integrations.wandb.WandbLoggerCallback``,
``ray.air.integrations.mlflow.MLflowLoggerCallback``) to the study's Tune run, so that every
report of every trial (the metrics of ``history.parquet``) reaches the tracker as Tune passes
it on. Any other Tune callback joins through ``run_study(spec, callbacks=[...])`` or
``safe_bc.cli.api.tune(job, callbacks=[...])`` (docs/curves.md).

Where they write, unless their own environment variables say otherwise:

* W&B: project ``$WANDB_PROJECT`` (else ``safe_bc``), group = the study's name, local files in
  ``results/<study>/wandb/`` (``$WANDB_DIR`` overrides); ``WANDB_MODE=offline`` keeps the runs
  on disk (``wandb sync`` uploads them later).
* MLflow: ``$MLFLOW_TRACKING_URI``, else a local SQLite store ``results/<study>/mlflow.db``
  (``mlflow ui --backend-store-uri sqlite:///results/<study>/mlflow.db``); experiment = the
  study's name.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Any, Literal

Tracker = Literal["none", "wandb", "mlflow"]
"""The trackers ``safe-bc tune --tracker`` knows."""

TRACKERS: tuple[str, ...] = ("none", "wandb", "mlflow")
"""Every :data:`Tracker`, in the CLI's order."""

PACKAGES = {"wandb": ("wandb", "wandb"), "mlflow": ("mlflow", "mlflow")}
"""Tracker -> (the module it imports, the safe_bc extra that installs it)."""


def check_tracker(name: str) -> None:
    """Refuse, in one line naming the fix, a tracker that is unknown or whose package is not
    installed (before the study starts).

    >>> check_tracker("none")
    >>> check_tracker("neptune")
    Traceback (most recent call last):
    ...
    ValueError: --tracker neptune: not a tracker (none, wandb, mlflow)
    """
    if name not in TRACKERS:
        raise ValueError(f"--tracker {name}: not a tracker ({', '.join(TRACKERS)})")
    if name == "none":
        return
    module, extra = PACKAGES[name]
    if importlib.util.find_spec(module) is None:
        raise ValueError(
            f"--tracker {name} needs the {module} package: pip install 'safe_bc[{extra}]' "
            f"(or pip install {module if name == 'wandb' else 'mlflow-skinny'})"
        )


def mlflow_store(out: Path) -> str:
    """The MLflow tracking URI a study in ``out`` logs to by default: a local SQLite store,
    ``results/<study>/mlflow.db`` (MLflow 3 refuses its old ``mlruns`` file store unless
    ``MLFLOW_ALLOW_FILE_STORE=true``).

    >>> mlflow_store(Path("/r/s"))
    'sqlite:////r/s/mlflow.db'
    """
    return f"sqlite:///{Path(out).resolve() / 'mlflow.db'}"


def tracker_callbacks(name: str, study: str, out: Path) -> list[Any]:
    """The Ray Tune callbacks of tracker ``name`` for the study ``study`` whose outputs go to
    ``out`` (``results/<study>/``); none for ``"none"``."""
    check_tracker(name)
    if name == "wandb":
        from ray.air.integrations.wandb import WandbLoggerCallback

        folder = Path(os.environ.get("WANDB_DIR") or out)
        folder.mkdir(parents=True, exist_ok=True)
        project = os.environ.get("WANDB_PROJECT") or "safe_bc"
        # the mode reaches the logging actors too (Ray forwards only the API key to them)
        mode = {"mode": os.environ["WANDB_MODE"]} if os.environ.get("WANDB_MODE") else {}
        return [WandbLoggerCallback(project=project, group=study, dir=str(folder), **mode)]
    if name == "mlflow":
        from ray.air.integrations.mlflow import MLflowLoggerCallback

        Path(out).mkdir(parents=True, exist_ok=True)  # SQLite makes the file, not its folder
        uri = os.environ.get("MLFLOW_TRACKING_URI") or mlflow_store(out)
        return [MLflowLoggerCallback(tracking_uri=uri, experiment_name=study)]
    return []
