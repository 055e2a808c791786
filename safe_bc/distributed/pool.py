"""A pool of persistent actors that replaces a dead actor and reruns its task."""

from __future__ import annotations

import collections
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import ray

T = TypeVar("T")


def run_on_actors(
    make_actor: Callable[[], Any],
    n_actors: int,
    tasks: Iterable[T],
    submit: Callable[[Any, T], ray.ObjectRef],
    on_result: Callable[[T, Any], None],
    *,
    max_retries: int = 3,
    on_restart: Callable[[int, T], None] | None = None,
) -> int:
    """Run every (hashable) task on ``n_actors`` long-lived actors, handling results as they come.

    A task whose actor dies (killed, out of memory, crashed) is given to a fresh
    actor, up to ``max_retries`` times; errors raised by the task itself propagate.
    All actors are killed on exit.

    Args:
        make_actor: creates one actor handle.
        submit: ``submit(actor, task) -> ObjectRef`` starts the task.
        on_result: ``on_result(task, value)`` in the driver, in completion order.
        on_restart: called with ``(slot, task)`` when an actor is replaced.

    Returns:
        The number of actor replacements.
    """
    queue = collections.deque(tasks)
    actors = [make_actor() for _ in range(min(n_actors, len(queue)))]
    pending: dict[ray.ObjectRef, tuple[int, T]] = {}
    failures: collections.Counter[T] = collections.Counter()
    restarts = 0

    def feed(slot: int) -> None:
        if queue:
            task = queue.popleft()
            pending[submit(actors[slot], task)] = (slot, task)

    try:
        for slot in range(len(actors)):
            feed(slot)
        while pending:
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            slot, task = pending.pop(ref)
            try:
                value = ray.get(ref)
            except ray.exceptions.RayActorError as e:
                failures[task] += 1
                if failures[task] > max_retries:
                    raise RuntimeError(
                        f"task {task!r}: its actor died {failures[task]} times ({e})"
                    ) from None
                ray.kill(actors[slot], no_restart=True)
                actors[slot] = make_actor()
                restarts += 1
                queue.appendleft(task)
                if on_restart is not None:
                    on_restart(slot, task)
            else:
                on_result(task, value)
            feed(slot)
    finally:
        for actor in actors:
            ray.kill(actor, no_restart=True)
    return restarts
