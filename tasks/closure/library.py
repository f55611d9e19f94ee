"""The closure's effect library, built once per model and effect list in a process (:func:`cached_library`)."""

from __future__ import annotations

from fe_core.closure.effects import build_library, registered_effects

__all__ = ["cached_library"]


def cached_library(model, effects) -> dict:
    """The effect library by kind, built once per model and effect list in a process (the screen,
    every check and the decision of a closure use the same; 320 patches take a second to build)."""
    cache = model.__dict__.setdefault("_closure_libraries", {})
    key = (tuple(registered_effects()), None if effects is None else tuple(effects))
    if key not in cache:
        cache[key] = {e.kind: e for e in build_library(model, effects)}
    return cache[key]
