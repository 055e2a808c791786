"""What the study and comparison runners use of the built-in methods' code beyond the registry
(:mod:`safe_bc.methods.registry`), so that they name no method: the tracks the methods validate
on, the critical-state shield as a handover, and an improved agent's net behind a shield that
does nothing."""

from __future__ import annotations

from typing import Any


def validation_seeds(n: int) -> list[int]:
    """The first ``n`` validation tracks (patients) of the methods' runs (an improvement run's
    validation, a self-imitation round's keep rule), disjoint from the held-out blocks: a
    comparison's ``tracks="validation"``
    (:func:`safe_bc.methods.improve.envs.validation_seeds`)."""
    from safe_bc.methods.improve.envs import validation_seeds as seeds

    return seeds(n)


def shielded(net: Any, fallback: Any, zone: Any, env_id: str) -> Any:
    """The policy source ``net`` with ``fallback`` acting in the states whose measured costs
    lie in ``zone`` (a :class:`safe_bc.selection.CriticalZone`): the critical-state shield of
    :mod:`safe_bc.methods.improve.shield` (an ``ImprovedSource``; it pickles cheaply)."""
    from safe_bc.methods.improve.shield import ImprovedSource, Shield

    return ImprovedSource(net, fallback, Shield(zone, env_id))


def unshielded(source: Any) -> Any:
    """``source`` as the net that acts, where a method's wrapper around it changes nothing (an
    improved agent without its shield: its net); any other source (a shielded agent, a net,
    ``None``) itself."""
    from safe_bc.methods.improve.shield import ImprovedSource

    if isinstance(source, ImprovedSource) and source.imitation is None:
        return source.improved
    return source
