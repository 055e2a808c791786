"""Held-out evaluation with one cached Parquet file per policy, for long result scripts.

:func:`evaluate_cached` sends every policy through the one evaluation path
(:func:`safe_bc.distributed.evaluate.evaluate_policies`) and keeps its per-episode rows in
``CACHE/<policy>.parquet``, stamped with a fingerprint of the policy's weights and configs,
the evaluation settings and the limits. A rerun evaluates only the policies whose stamp
differs, so an interrupted evaluation resumes and a table can be rebuilt without replaying
hundreds of CarRacing episodes. Policies can also be spread over ``processes`` local
processes (no Ray needed: a 16-core machine without it).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import multiprocessing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch


def fingerprint(obj: Any) -> str:
    """SHA-256 of a policy source's content: tensors and arrays by their bytes, dataclasses
    by their fields, mappings by sorted keys (independent of pickling and of the process).

    >>> fingerprint({"a": 1.0}) == fingerprint({"a": 1.0}) != fingerprint({"a": 2.0})
    True
    """
    h = hashlib.sha256()

    def feed(x: Any) -> None:
        if isinstance(x, torch.Tensor):
            x = x.detach().cpu().numpy()
        if isinstance(x, np.ndarray):
            h.update(f"{x.dtype}{x.shape}".encode())
            h.update(np.ascontiguousarray(x).tobytes())
        elif dataclasses.is_dataclass(x) and not isinstance(x, type):
            h.update(type(x).__qualname__.encode())
            for f in dataclasses.fields(x):
                h.update(f.name.encode())
                feed(getattr(x, f.name))
        elif isinstance(x, Mapping):
            for k in sorted(x, key=str):
                h.update(repr(k).encode())
                feed(x[k])
        elif isinstance(x, list | tuple):
            h.update(f"{type(x).__name__}{len(x)}".encode())
            for v in x:
                feed(v)
        else:
            h.update(repr(x).encode())

    feed(obj)
    return h.hexdigest()


def _stamp(key: str, source: Any, config: Any, limits: np.ndarray | None) -> dict[str, Any]:
    settings = dataclasses.asdict(config)
    settings.pop("workers")  # where episodes run changes nothing
    stamp = {
        "policy": key,
        "fingerprint": fingerprint(source),
        "eval": settings,
        "limits": None if limits is None else [float(x) for x in limits],
    }
    return json.loads(json.dumps(stamp, default=str))


def cache_path(cache: Path, key: str) -> Path:
    """``CACHE/<key with '/' as '-'>.parquet``."""
    return cache / f"{key.replace('/', '-')}.parquet"


def _evaluate_one(key: str, source: Any, config: Any, limits: np.ndarray | None) -> pd.DataFrame:
    from safe_bc.distributed.evaluate import LOCKSTEP_ENVS, evaluate_policies

    torch.set_num_threads(1)  # one core per process
    config = dataclasses.replace(config, workers=0)
    episodes, _ = evaluate_policies({key: source}, config, thresholds=limits, progress=False,
                                    envs_per_worker=LOCKSTEP_ENVS)  # fmt: skip
    return episodes


def evaluate_cached(
    sources: Mapping[str, Any],
    config: Any,
    limits: np.ndarray | None,
    cache: Path,
    *,
    processes: int = 0,
    progress: bool = True,
) -> pd.DataFrame:
    """Per-episode rows of every policy on ``config``'s held-out seeds, in ``sources`` order.

    Args:
        sources: policy key -> source (``build() -> Policy``).
        config: an :class:`safe_bc.evaluation.EvalConfig`; its ``workers`` Ray actors evaluate
            the missing policies together (``processes`` = 0).
        limits: the demonstrations' ``d_s``.
        cache: folder of the per-policy files.
        processes: > 0: the missing policies go to this many local processes instead, one
            policy per task, each in-process (no Ray).
    """
    from safe_bc.data.store import read_table, write_table_atomic
    from safe_bc.provenance import run_metadata

    cache.mkdir(parents=True, exist_ok=True)
    stamps = {key: _stamp(key, src, config, limits) for key, src in sources.items()}
    frames: dict[str, pd.DataFrame] = {}
    for key in sources:
        path = cache_path(cache, key)
        if path.exists():
            frame, meta = read_table(path)
            if {k: meta.get(k) for k in stamps[key]} == stamps[key]:
                frames[key] = frame
    missing = [key for key in sources if key not in frames]

    def keep(key: str, frame: pd.DataFrame) -> None:
        write_table_atomic(cache_path(cache, key), frame, run_metadata(**stamps[key]))
        frames[key] = frame
        if progress:
            print(f"evaluated {key}: {len(frame)} episodes, reward "
                  f"{frame['reward'].mean():.1f}", flush=True)  # fmt: skip

    if missing and processes > 0:
        ctx = multiprocessing.get_context("spawn")
        with ctx.Pool(min(processes, len(missing))) as pool:
            jobs = {k: pool.apply_async(_evaluate_one, (k, sources[k], config, limits))
                    for k in missing}  # fmt: skip
            for key, job in jobs.items():
                keep(key, job.get())
    elif missing:
        from safe_bc.distributed.evaluate import LOCKSTEP_ENVS, evaluate_policies

        episodes, _ = evaluate_policies({k: sources[k] for k in missing}, config,
                                        thresholds=limits, progress=progress,
                                        envs_per_worker=LOCKSTEP_ENVS)  # fmt: skip
        for key, frame in episodes.groupby("policy", sort=False):
            keep(str(key), frame.reset_index(drop=True))
    return pd.concat([frames[k] for k in sources], ignore_index=True)
