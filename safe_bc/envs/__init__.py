"""What every environment shares: :class:`EnvConfig` and the info contract (``info.py``).
Building a task's env is the task registry's (:func:`safe_bc.tasks.make_env`); the tasks' own
envs live in their folders (``safe_bc/tasks/<name>/``)."""

from safe_bc.envs.config import EnvConfig

__all__ = ["EnvConfig"]
