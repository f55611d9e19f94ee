"""Pure pieces of the adaptive sampling loop (Section 2.3 and Table 2 of Zhou & Tang).

Each function takes arrays and returns arrays, so the loop can be tested and
replayed without the orchestration layer:

* response errors: the relative residual vector of Eq. (5), the overall error
  of Eq. (6b) and the per-sensor error of Eq. (15);
* the sampling distribution: a normal distribution fitted to the best ``z``
  FE-evaluated samples (step f), and candidate draws from it that never leave
  the valid domain (step g);
* selection of the ``s`` candidates with the smallest predicted error that
  are at least a minimum distance apart (step d);
* the stopping rule (step e).

Response layout (Eq. 5): for ``n`` sensors and ``p`` frequencies the error
vector is frequency-major, ``[du_11 .. du_n1, du_12 .. du_n2, ..., du_np]``,
so a (p, n) amplitude array flattens to it with ``reshape(-1)``.

Complex data (beyond the paper): :func:`complex_relative_residuals` gives the
real and imaginary parts of ``(Z - H) / |H|``, real parts first; Eq. (6b)
applied to that vector is the overall error, and it is Eq. (6b) itself when
only amplitudes are measured (then the vector is the amplitude residuals).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "relative_residuals",
    "complex_relative_residuals",
    "overall_error",
    "per_sensor_error",
    "uniform_samples",
    "SamplingDistribution",
    "fit_distribution",
    "draw_candidates",
    "select_diverse",
    "default_min_distance",
    "StopDecision",
    "stopping_rule",
    "TrustRegion",
    "update_trust_region",
    "local_training_set",
    "inverse_receptance",
    "receptance_from_inverse",
    "refine_on_emulator",
]


def relative_residuals(model_amplitude: np.ndarray, measured_amplitude: np.ndarray) -> np.ndarray:
    """Signed relative residuals ``(|Z_model| - u_meas) / u_meas`` in the layout of Eq. (5).

    Parameters
    ----------
    model_amplitude : ndarray, shape (..., p, n), m/N
        Model amplitudes for one or many samples.
    measured_amplitude : ndarray, shape (p, n), m/N
        Positive measured amplitudes.

    Returns
    -------
    ndarray, shape (..., p * n)
        Frequency-major, sensors fastest.
    """
    model_amplitude = np.asarray(model_amplitude, dtype=float)
    measured_amplitude = np.asarray(measured_amplitude, dtype=float)
    rel = (model_amplitude - measured_amplitude) / measured_amplitude
    return rel.reshape(rel.shape[:-2] + (-1,))


def complex_relative_residuals(model_frf: np.ndarray, measured_frf: np.ndarray) -> np.ndarray:
    """Real and imaginary parts of ``(Z_model - H_meas) / |H_meas|``, real parts first.

    The phase carries what the amplitude drops (the sign of a mode's
    contribution, which side of a resonance a line is on); dividing by
    ``|H_meas|`` keeps the relative weighting of Eq. (5), and the two parts
    are smooth in the parameters where the amplitude residual has a kink.

    Parameters
    ----------
    model_frf : ndarray, shape (..., c), complex
        Model FRF at ``c`` measured values (lines x channels, flattened).
    measured_frf : ndarray, shape (c,), complex, non-zero

    Returns
    -------
    ndarray, shape (..., 2 c)
        ``[Re r_1 .. Re r_c, Im r_1 .. Im r_c]``.
    """
    measured_frf = np.asarray(measured_frf, dtype=complex)
    r = (np.asarray(model_frf, dtype=complex) - measured_frf) / np.abs(measured_frf)
    return np.concatenate([r.real, r.imag], axis=-1)


def overall_error(residuals: np.ndarray) -> np.ndarray:
    """Eq. (6b): mean absolute relative residual, shape (...,) from (..., p * n)."""
    return np.mean(np.abs(residuals), axis=-1)


def per_sensor_error(residuals: np.ndarray, n_sensors: int) -> np.ndarray:
    """Eq. (15): mean absolute relative residual per sensor, shape (..., n) from (..., p * n)."""
    r = np.asarray(residuals)
    return np.mean(np.abs(r.reshape(r.shape[:-1] + (-1, n_sensors))), axis=-2)


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


@dataclass(frozen=True)
class StopDecision:
    """Whether the loop stops after an FE stage, and why."""

    stop: bool
    converged: bool
    reason: str


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


# -- the trust-region loop (beyond the paper; config ``loop = "trust-region"``) ----------------------
#
# Measured on the benchmark (docs/update-results.md): the paper's normal distribution of the best z samples
# collapses onto a wrong basin (7-22 % after 240 FE runs). Here the candidates are uniform in a box that
# follows the best FE sample (TuRBO, Eriksson et al. 2019), the MRGP emulates the model's inverse receptance
# near it (1/Z is nearly linear in a segment's stiffness where one mode dominates) and the error of a
# candidate is computed from the emulated response (a composite objective, Astudillo and Frazier 2019),
# and Gauss-Newton steps on the emulator's mean add candidates where it predicts the minimum.


@dataclass(frozen=True)
class TrustRegion:
    """A box around the best FE sample: side ``length`` times the search box's, per parameter.

    ``successes``/``failures`` count consecutive iterations that did / did not improve the best error
    ``best`` (by more than a relative 1e-3).
    """

    centre: np.ndarray
    length: float
    successes: int = 0
    failures: int = 0
    best: float = float("inf")

    def box(self, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(low, high), shape (m,) each: the trust region clipped to the search box."""
        lower, upper = np.asarray(lower, float), np.asarray(upper, float)
        half = 0.5 * self.length * (upper - lower)
        return np.maximum(lower, self.centre - half), np.minimum(upper, self.centre + half)


def update_trust_region(previous: TrustRegion | None, X: np.ndarray, errors: np.ndarray, *,
                        success_tolerance: int = 2, failure_tolerance: int = 1, min_length: float = 2.0**-7,
                        max_length: float = 1.0, rtol: float = 1e-3) -> TrustRegion:
    """The trust region after an FE batch: centred on the best sample of ``X`` (r, m), ``errors`` (r,).

    The side doubles after ``success_tolerance`` consecutive improving iterations and halves after
    ``failure_tolerance`` failing ones (TuRBO's rule for a batch larger than the dimension), within
    [``min_length``, ``max_length``]; the first region (``previous`` None) is the whole box.
    """
    errors = np.asarray(errors, float)
    i = int(np.argmin(errors))
    best = float(errors[i])
    if previous is None:
        return TrustRegion(np.asarray(X, float)[i].copy(), max_length, 0, 0, best)
    improved = best < previous.best - rtol * abs(previous.best)
    successes, failures = (previous.successes + 1, 0) if improved else (0, previous.failures + 1)
    length = previous.length
    if successes >= success_tolerance:
        length, successes = min(2.0 * length, max_length), 0
    if failures >= failure_tolerance:
        length, failures = max(0.5 * length, min_length), 0
    return TrustRegion(np.asarray(X, float)[i].copy(), length, successes, failures, min(best, previous.best))


def local_training_set(X: np.ndarray, region: TrustRegion, lower, upper, minimum: int) -> np.ndarray:
    """Indices of the samples inside twice the trust region (max-norm, relative to the box), at least the
    ``minimum`` nearest: the emulator is fitted where the candidates are, with one length scale per input."""
    X = np.asarray(X, float)
    width = np.asarray(upper, float) - np.asarray(lower, float)
    dist = np.max(np.abs(X - region.centre) / width, axis=1)
    inside = np.flatnonzero(dist <= region.length)
    if inside.size >= minimum:
        return inside
    return np.sort(np.argsort(dist, kind="stable")[:minimum])


def inverse_receptance(Z: np.ndarray) -> np.ndarray:
    """Real and imaginary parts of ``1 / Z``, (..., k) complex -> (..., 2 k) real, real parts first."""
    g = 1.0 / np.asarray(Z, complex)
    return np.concatenate([g.real, g.imag], axis=-1)


def receptance_from_inverse(G: np.ndarray) -> np.ndarray:
    """The inverse of :func:`inverse_receptance`: (..., 2 k) real -> (..., k) complex."""
    G = np.asarray(G, float)
    k = G.shape[-1] // 2
    return 1.0 / (G[..., :k] + 1j * G[..., k:])


def refine_on_emulator(residuals_of, starts: np.ndarray, low: np.ndarray, high: np.ndarray,
                       max_evaluations: int = 50, tolerance: float = 1e-8) -> np.ndarray:
    """Gauss-Newton (trust-region least squares) on the emulator's mean from each start, inside [low, high].

    ``residuals_of(x)`` gives the residual vector the emulator predicts at x (m,). Returns the end points,
    shape (len(starts), m): candidates where the emulator's mean is smallest. ``tolerance``: scipy's ``ftol``,
    ``xtol`` and ``gtol``; near machine precision the runs end on ``max_evaluations`` or at a stationary
    point, so an end point moves continuously with the data (a loose test that stops one step earlier for a
    change in the last digits moves it by a whole step).
    """
    from scipy.optimize import least_squares

    out = []
    for x0 in np.asarray(starts, float):
        sol = least_squares(residuals_of, np.clip(x0, low, high), bounds=(low, high), method="trf",
                            max_nfev=max_evaluations, diff_step=1e-6, ftol=tolerance, xtol=tolerance,
                            gtol=tolerance)
        out.append(sol.x)
    return np.array(out).reshape(-1, len(low))
