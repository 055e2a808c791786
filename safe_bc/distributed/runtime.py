"""Starting or joining Ray."""

from __future__ import annotations

import os

import ray


def ensure_ray(num_cpus: int | None = None) -> None:
    """Join the cluster named by ``RAY_ADDRESS``, else start a local Ray (no-op if running).

    ``num_cpus`` only applies to a new local instance; it is never passed when
    connecting to a cluster (Ray refuses it there).
    """
    if ray.is_initialized():
        return
    if os.environ.get("RAY_ADDRESS"):
        ray.init()
        return
    # A private local instance needs no token auth (Ray >= 2.59 enables it by default).
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    ray.init(address="local", num_cpus=num_cpus, include_dashboard=False)


def cluster_cpus() -> float:
    """Total CPUs of the running Ray cluster."""
    return float(ray.cluster_resources().get("CPU", 1.0))


def cpus_per_actor(workers: int) -> float:
    """CPUs to reserve per actor so ``workers`` actors fit the cluster (never above 1).

    Reserving more than the cluster has makes actors wait forever, silently.
    """
    return min(1.0, cluster_cpus() / workers)
