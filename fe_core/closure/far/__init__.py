"""Far from the model's basin: a sizeable effect found by exact (not linearised) evaluation of the candidates on a
reduced model (:mod:`.reduced`, :mod:`.search`), and what the model's own error would give (:mod:`.misfit`)."""

from .reduced import ReducedModel, lowrank_factors
from .search import Found, exact_search, reduced_fit, size_grid, spread

__all__ = ["ReducedModel", "lowrank_factors", "Found", "exact_search", "reduced_fit", "size_grid", "spread"]
