"""The pure steps of the paper's adaptive sampling loop (Section 2.3 and Table 2 of Zhou & Tang).

Each function takes arrays and returns arrays, so the loop can be tested and replayed without the
orchestration layer:

* the first samples, uniform in the search box (step c);
* the sampling distribution: a normal distribution fitted to the best ``z`` FE-evaluated samples
  (step f), and candidate draws from it that never leave the valid domain (step g);
* selection of the ``s`` candidates with the smallest predicted error that are at least a minimum
  distance apart (step d);
* the stopping rule (step e).

:mod:`.paper` chains them with the MRGP (:mod:`.emulation`) into the loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import StopDecision

__all__ = [
    "uniform_samples",
    "SamplingDistribution",
    "fit_distribution",
    "draw_candidates",
    "select_diverse",
    "default_min_distance",
    "stopping_rule",
]


def uniform_samples(n: int, lower: np.ndarray, upper: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``n`` samples uniform in the box, shape (n, m), with the open lower edge -1 excluded."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    x = rng.uniform(lower, upper, size=(n, lower.size))
    return _keep_inside(x, lower, upper, rng, lambda k: rng.uniform(lower, upper, size=(k, lower.size)))


@dataclass(frozen=True)
class SamplingDistribution:
    """An axis-aligned normal distribution over the parameters.

    Attributes
    ----------
    mean : ndarray, shape (m,)
    std : ndarray, shape (m,)
    """

    mean: np.ndarray
    std: np.ndarray

    @property
    def radius(self) -> float:
        """Root of the summed variances: the distribution's typical spread."""
        return float(np.sqrt(np.sum(self.std**2)))


def fit_distribution(
    X: np.ndarray, errors: np.ndarray, z: int, std_floor: float = 1e-4
) -> SamplingDistribution:
    """Step f: mean and standard deviation of the ``z`` samples with the smallest errors.

    Parameters
    ----------
    X : ndarray, shape (r, m)
        All FE-evaluated samples so far.
    errors : ndarray, shape (r,)
        Their overall errors (Eq. 6b).
    z : int
    std_floor : float
        Lower bound on each standard deviation, so that the candidates keep
        some spread when the best samples coincide in one parameter.
    """
    best = np.argsort(errors, kind="stable")[: min(z, len(errors))]
    top = np.asarray(X)[best]
    std = top.std(axis=0, ddof=1) if top.shape[0] > 1 else np.zeros(top.shape[1])
    return SamplingDistribution(mean=top.mean(axis=0), std=np.maximum(std, std_floor))


def draw_candidates(
    dist: SamplingDistribution,
    w: int,
    lower: np.ndarray,
    upper: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Step g: ``w`` candidates from the normal distribution, truncated to the search box.

    Draws outside ``(lower, upper]`` (for stiffness factors the valid domain
    starts above -1) are redrawn, so no candidate leaves the domain.

    Returns
    -------
    ndarray, shape (w, m)
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    draw = lambda k: rng.normal(dist.mean, dist.std, size=(k, dist.mean.size))  # noqa: E731
    return _keep_inside(draw(w), lower, upper, rng, draw)


def _keep_inside(x, lower, upper, rng, redraw, max_rounds: int = 1000) -> np.ndarray:
    for _ in range(max_rounds):
        bad = np.any((x <= lower) | (x > upper), axis=1)
        if not bad.any():
            return x
        x[bad] = redraw(int(bad.sum()))
    raise ValueError(
        "could not draw samples inside the search bounds: the sampling distribution lies outside them"
    )


def default_min_distance(dist: SamplingDistribution | None, lower, upper, factor: float = 0.1) -> float:
    """Default minimum distance between samples selected in one iteration.

    ``factor`` times the spread of the distribution the candidates come from
    (the uniform box's standard deviation on the first iteration). Scaling
    with the spread keeps the constraint meaningful as the search narrows:
    an absolute distance would either be irrelevant early or forbid any
    selection late.
    """
    if dist is None:
        std = (np.asarray(upper, float) - np.asarray(lower, float)) / np.sqrt(12.0)
        return float(factor * np.sqrt(np.sum(std**2)))
    return factor * dist.radius


def select_diverse(
    candidates: np.ndarray, scores: np.ndarray, s: int, min_distance: float, exclude: np.ndarray | None = None
) -> np.ndarray:
    """Step d: indices of ``s`` low-score candidates, pairwise at least ``min_distance`` apart.

    Greedy in order of increasing score. Candidates closer than
    ``min_distance`` to an already evaluated sample (``exclude``) are skipped
    too, so the FE model never runs twice on (nearly) the same point. If the
    pool cannot supply ``s`` such points, the distance is halved until it can
    (down to zero).

    Parameters
    ----------
    candidates : ndarray, shape (w, m)
    scores : ndarray, shape (w,)
        Predicted overall errors; NaN scores are never selected.
    s : int
    min_distance : float
    exclude : ndarray, shape (r, m), optional

    Returns
    -------
    ndarray, shape (<= s,), int
    """
    order = np.argsort(np.where(np.isfinite(scores), scores, np.inf), kind="stable")
    order = order[np.isfinite(scores[order])]
    d = float(min_distance)
    while True:
        chosen: list[int] = []
        taken = np.empty((0, candidates.shape[1])) if exclude is None else np.asarray(exclude, float)
        for i in order:
            x = candidates[i]
            if taken.shape[0] and np.min(np.sum((taken - x) ** 2, axis=1)) < d * d:
                continue
            chosen.append(int(i))
            taken = np.vstack([taken, x])
            if len(chosen) == s:
                return np.array(chosen)
        if d == 0.0:
            return np.array(chosen, dtype=int)
        d = d / 2 if d > 1e-9 else 0.0


def stopping_rule(
    best_error: float,
    threshold: float,
    iteration: int,
    max_iterations: int,
    fe_evaluations: int,
    max_fe_evaluations: int,
    batch: int,
) -> StopDecision:
    """Step e: stop when the best FE error is below the threshold or a budget is spent.

    Parameters
    ----------
    best_error : float
        Smallest overall error of all FE-evaluated samples.
    threshold : float
        e.g. 0.01 for 1 %.
    iteration : int
        1-based index of the iteration whose FE stage just finished.
    batch : int
        FE runs the next iteration would need.
    """
    if best_error <= threshold:
        return StopDecision(True, True, f"overall error {best_error:.4%} <= threshold {threshold:.4%}")
    if iteration >= max_iterations:
        return StopDecision(True, False, f"iteration budget ({max_iterations}) spent")
    if fe_evaluations + batch > max_fe_evaluations:
        return StopDecision(True, False, f"FE budget ({max_fe_evaluations}) would be exceeded")
    return StopDecision(False, False, "continue")
