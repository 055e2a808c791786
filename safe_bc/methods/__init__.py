"""Improvement methods: one interface (:class:`MethodSpec`, :class:`Start`, :class:`Improved`)
and one registry (:data:`METHODS`) that the study's stages, the comparison runner and the
command line read (:mod:`safe_bc.methods.registry`). The built-in methods are registered
here, one line each, in the order study stages run; their runners live beside their code, as do
the records and runners of the commands from before ``safe-bc method NAME``
(:data:`METHOD_COMMANDS`)."""

from __future__ import annotations

from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.methods.queries.config import QueryConfig
from safe_bc.methods.registry import (
    METHOD_COMMANDS,
    METHODS,
    Improved,
    MethodCommand,
    MethodSpec,
    Runner,
    Start,
    method_of,
    method_of_config,
    register_command,
    register_method,
)
from safe_bc.methods.selfimprove.config import SelfImproveConfig

__all__ = [
    "METHODS",
    "METHOD_COMMANDS",
    "Improved",
    "MethodCommand",
    "MethodSpec",
    "Runner",
    "Start",
    "method_of",
    "method_of_config",
    "register_command",
    "register_method",
]

register_method(
    MethodSpec(
        name="improve",
        config=ImproveConfig,
        runner="safe_bc.methods.improve.stage:run",
        identity="safe_bc.methods.improve.stage:identity",
        metrics=("improve_seconds", "improve_kept_iteration"),
        summed=("improve_seconds",),
        label="improving",
        flat_field=True,
    )
)
register_method(
    MethodSpec(
        name="queries",
        config=QueryConfig,
        runner="safe_bc.methods.queries.stage:run",
        metrics=("queries_total", "queries_per_episode", "queries_seconds"),
        summed=("queries_total", "queries_seconds"),
        label="querying the expert",
    )
)
register_method(
    MethodSpec(
        name="selfimprove",
        config=SelfImproveConfig,
        runner="safe_bc.methods.selfimprove.stage:run",
        metrics=("selfimprove_accepted_rounds", "selfimprove_kept_steps", "selfimprove_seconds"),
        summed=("selfimprove_kept_steps", "selfimprove_seconds"),
        label="self-imitating",
        identity="safe_bc.methods.selfimprove.stage:identity",
        start_modes=("mix",),
        shares_rounds=True,
        flat_field=True,
    )
)
register_command(
    MethodCommand(
        name="query",
        job="safe_bc.methods.queries.command:QueryJob",
        runner="safe_bc.methods.queries.command:query",
    )
)
register_command(
    MethodCommand(
        name="improve",
        job="safe_bc.methods.improve.command:ImproveJob",
        runner="safe_bc.methods.improve.command:improve",
        configs=(("ppo_lagrangian", "config"), ("selfimitation", "selfimitation")),
    )
)
