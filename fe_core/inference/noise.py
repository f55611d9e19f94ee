"""A noise model per line and channel: the standard deviation of ``ln|H|`` at every measured value.

Real tests do not have one noise level: a sensor has a floor in its own units (near the anti-resonances and
at the band's ends, where the response is small, the relative noise is large), the force adds a relative part,
channels have their own averages. :class:`NoiseModel` holds ``sigma`` (p, n), the standard deviation of the log
amplitude residual ``ln(|Z| / u)`` at every value, and where it came from (``source``):

* ``"configured"``: one relative level for every value (``--noise``);
* ``"coherence"``: from the measured coherence and the number of averages (the random error of an H1
  estimate, :func:`fe_core.inference.coherence_noise.frf_random_error`; a residual divided by it is Student-t
  with ``2 (n - 1)`` degrees of freedom);
* ``"records"``: the same, from raw force and response records (the hits are the averages);
* ``"estimated"``: from a residual, as a relative term and a floor per channel,
  ``sigma_ij^2 = a_j^2 + (b_j / u_ij)^2`` (``b_j`` in the channel's units, the data's m/N), fitted robustly to
  the residual's second differences along frequency (:func:`estimate_noise_model`). A misfit that is smooth in
  frequency adds little to them; the few large ones a misfit leaves near resonances are clipped.

The residual divided by ``sigma`` is white with unit variance if the model explains the data; the tests of
:mod:`fe_core.inference.residual` take it so (:func:`noise_model_test`: against white noise drawn from the same
model, with the model estimated again from each draw when it was estimated from the residual).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .levels import CLIP, CLIP_FACTOR, _clipped_level, frequency_bands

__all__ = ["NoiseModel", "Estimated", "NOISE_SOURCES", "estimate_noise_model", "calibrate", "noise_model_test",
           "differences_per_channel", "MIN_DIFFERENCES", "one_level", "judged_by"]

NOISE_SOURCES = ("configured", "coherence", "records", "estimated")

#: Second differences a channel needs for a relative term and a floor of its own (else one level for all values).
MIN_DIFFERENCES = 100
#: Iterations of the reweighted fit (it settles in 10-30; a draw that has not is within 1e-3 by then).
MAX_ITERATIONS = 60
#: White-noise draws of the test against an estimated model (:func:`noise_model_test`).
NULL_DRAWS = 200


@dataclass(frozen=True, eq=False)
class NoiseModel:
    """The standard deviation of ``ln|H|`` at every value, and where it came from.

    Attributes
    ----------
    sigma : ndarray, shape (p, n)
        Per line and channel (NaN where a value is not measured or not kept).
    source : str
        One of :data:`NOISE_SOURCES`.
    relative, floor : ndarray, shape (n,), or None
        The estimated model's relative term ``a_j`` and floor ``b_j`` (the data's units) per channel.
    t_dof : ndarray, shape (p, n), or None
        Where ``sigma`` is itself estimated from the data (coherence of ``n`` averages): the residual over it is
        Student-t with these degrees of freedom, ``2 (n - 1)``; None: normal.
    scale : ndarray, shape (n,), or None
        A measured model's level per channel as checked against a residual (:func:`calibrate`; ``sigma`` is
        then the measured one times it); None: as measured.
    """

    sigma: np.ndarray
    source: str
    relative: np.ndarray | None = None
    floor: np.ndarray | None = None
    t_dof: np.ndarray | None = None
    scale: np.ndarray | None = None

    @classmethod
    def configured(cls, level: float, shape: tuple[int, int]) -> "NoiseModel":
        return cls(np.full(shape, float(level)), "configured")

    @classmethod
    def from_coherence(cls, coherence: np.ndarray, averages, amplitude: np.ndarray,
                       source: str = "coherence") -> "NoiseModel":
        """From the measured coherence (p, n) and the number of averages (scalar, (n,) or (p, n)), smoothed along
        frequency (:func:`smooth_measured`); ``amplitude`` (p, n): the measured amplitudes in each channel's own
        units, lines in frequency order. ``source`` "records" when both came from raw records (the hits)."""
        from .coherence_noise import frf_random_error

        g2 = np.asarray(coherence, float)
        n = np.broadcast_to(np.asarray(averages, float), g2.shape)
        sigma = smooth_measured(frf_random_error(g2, n), amplitude)
        return cls(sigma, source)

    def lines(self, which) -> "NoiseModel":
        """The model on a subset of the lines (a boolean or index array over the first axis)."""
        return NoiseModel(self.sigma[which], self.source, self.relative, self.floor,
                          None if self.t_dof is None else self.t_dof[which], self.scale)

    def describe(self) -> str:
        s = self.sigma[np.isfinite(self.sigma)]
        spread = f"{np.median(s):.3%} median, {np.min(s):.3%}-{np.max(s):.3%}" if s.size else "none"
        if self.source == "estimated" and self.relative is not None:
            return (f"estimated from the residual: relative {np.median(self.relative):.3%} (channels "
                    f"{np.min(self.relative):.3%}-{np.max(self.relative):.3%}) and a floor per channel; "
                    f"sigma of ln|H| {spread}")
        scaled = "" if self.scale is None else (f", its level x{np.min(self.scale):.3g}-{np.max(self.scale):.3g} "
                                                "from the residual's second differences")
        return f"{self.source}: sigma of ln|H| {spread}{scaled}"

    def to_dict(self) -> dict:
        s = self.sigma[np.isfinite(self.sigma)]
        out = {"source": self.source, "sigma_median": float(np.median(s)) if s.size else None,
               "sigma_min": float(np.min(s)) if s.size else None, "sigma_max": float(np.max(s)) if s.size else None}
        if self.relative is not None:
            out["relative"] = [float(v) for v in self.relative]
        if self.floor is not None:
            out["floor"] = [float(v) for v in self.floor]
        if self.scale is not None:
            out["scale"] = [float(v) for v in self.scale]
        return out


@dataclass(frozen=True, eq=False)
class Estimated:
    """"Estimate the noise model from each residual tested": the measured amplitudes in each channel's own units,
    shape (p, n), on the lines the residuals have (the floor of :func:`estimate_noise_model` is in those units).
    Passed where a noise level is (``noise=``), so a residual's test estimates its model itself."""

    amplitude: np.ndarray


#: Lines either side over which a measured sigma's local departure from its smooth model is averaged.
SMOOTH_LINES = 5


def smooth_measured(sigma: np.ndarray, amplitude: np.ndarray, half: int = SMOOTH_LINES) -> np.ndarray:
    """A measured sigma per line (p, n) with its sampling scatter taken out: per channel the model
    ``a^2 + b^2 / u^2`` (a relative term and a floor, :func:`estimate_noise_model`'s) fitted to ``sigma^2``, times
    the running mean over ``2 half + 1`` lines of ``sigma^2`` over that model (what the model misses locally:
    leakage near a sharp peak, fewer averages on some lines).

    The sigma of one line from the coherence of ``n`` averages scatters by ``1 / sqrt(2 (n - 1))`` (33 % at 5
    averages, 24 % at 10): as weights of a least-squares fit, that scatter, which comes from the same averages as
    the residual, made the 95 % intervals of simulated hammer tests cover 0.91 (measured while building it, issue 40); the
    smoothed sigma keeps the measured level and shape. ``sigma^2`` is ``sigma_true^2 chi2(nu) / nu``, whose
    variance goes with its mean squared whatever ``nu``: the fit's weights are ``1 / v^2``. Non-finite values
    (zero coherence) are left out of the fit and keep their value. A zero (a coherence written as exactly 1: the
    export's digits, not a perfect line; it would weigh its residual infinitely) is left out of the fit and gets
    the smoothed value of its line."""
    s2 = np.asarray(sigma, float) ** 2
    u = np.asarray(amplitude, float)
    ok = np.isfinite(s2) & (s2 > 0) & np.isfinite(u) & (u > 0)
    zero = (s2 == 0) & np.isfinite(u) & (u > 0)
    out = np.array(s2)
    for j in range(s2.shape[1]):
        k = ok[:, j]
        if k.sum() < 3:
            continue
        x0, x1, y = np.ones(k.sum()), 1.0 / u[k, j] ** 2, s2[k, j]
        a2, b2 = np.median(y), 0.0
        for _ in range(MAX_ITERATIONS):  # variance regression with weights 1 / v^2 (the scatter of a chi-square)
            v = np.maximum(a2 * x0 + b2 * x1, 1e-300)
            new_a, new_b = _nnls2(x0, x1, y, 1.0 / v**2)
            if abs(new_a - a2) <= 1e-9 * max(a2, 1e-300) and abs(new_b - b2) <= 1e-9 * max(b2, 1e-300):
                a2, b2 = new_a, new_b
                break
            a2, b2 = new_a, new_b
        model = a2 + b2 / u[:, j] ** 2
        ratio = np.where(k, s2[:, j] / model, 0.0)
        kernel = np.ones(2 * half + 1)
        local = np.convolve(ratio, kernel, "same") / np.maximum(np.convolve(k.astype(float), kernel, "same"), 1)
        fill = k | zero[:, j]
        out[fill, j] = (model * local)[fill]
    return np.sqrt(out)


# -- the estimated model --------------------------------------------------------------------------------------
def _bands(freqs_hz) -> list[np.ndarray]:
    return [b for b in frequency_bands(freqs_hz) if b.size >= 3]


def _design(u: np.ndarray, bands: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per channel, for every second difference ``r[i-1] - 2 r[i] + r[i+1]`` of a band: the coefficients of
    ``a^2`` (6) and of ``b^2`` (``1/u[i-1]^2 + 4/u[i]^2 + 1/u[i+1]^2``), shapes (m, n) each."""
    inv = 1.0 / np.asarray(u, float) ** 2
    x1 = np.concatenate([inv[b[:-2]] + 4.0 * inv[b[1:-1]] + inv[b[2:]] for b in bands])
    return np.full(x1.shape, 6.0), x1


def _second_differences(r: np.ndarray, bands: list[np.ndarray]) -> np.ndarray:
    """(..., m, n) second differences along the lines of every band of ``r`` (..., p, n)."""
    return np.concatenate([np.diff(r[..., b, :], n=2, axis=-2) for b in bands], axis=-2)


def _nnls2(x0, x1, y, w):
    """Weighted least squares of ``y ~ x0 a + x1 b`` with ``a, b >= 0``, batched over the leading axes (the sums
    run over the last): the interior solution where it is feasible, else the better of the two axes (with two
    unknowns the constrained optimum lies on one of them)."""
    s00, s01, s11 = (w * x0 * x0).sum(-1), (w * x0 * x1).sum(-1), (w * x1 * x1).sum(-1)
    t0, t1 = (w * x0 * y).sum(-1), (w * x1 * y).sum(-1)
    det = s00 * s11 - s01**2
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (s11 * t0 - s01 * t1) / det
        b = (s00 * t1 - s01 * t0) / det
        a_only = np.maximum(t0 / s00, 0.0)
        b_only = np.maximum(t1 / s11, 0.0)
    # objective (up to a constant) of a candidate: a^2 s00 + 2 a b s01 + b^2 s11 - 2 (a t0 + b t1)
    obj_a = a_only**2 * s00 - 2 * a_only * t0
    obj_b = b_only**2 * s11 - 2 * b_only * t1
    use_a = obj_a <= obj_b
    edge_a, edge_b = np.where(use_a, a_only, 0.0), np.where(use_a, 0.0, b_only)
    inside = (a >= 0) & (b >= 0) & np.isfinite(a) & np.isfinite(b)
    return np.where(inside, a, edge_a), np.where(inside, b, edge_b)


def _fit(d2: np.ndarray, x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(a^2, b^2) >= 0`` of the variance model ``x0 a^2 + x1 b^2`` of squared second differences ``d2``
    (..., m), batched over the leading axes: iteratively reweighted non-negative least squares (weights
    ``1 / v^2``: the squares of normal differences have variance ``2 v^2``), the differences beyond :data:`CLIP`
    of their standard deviation left out and the kept ones' clipped second moment corrected
    (:data:`CLIP_FACTOR`). Starts from the lower quartile's level with no floor, so the iteration rises to the
    noise's fixed point, not to one a misfit at many lines would hold up (as the scalar estimate)."""
    from scipy import stats  # here, not at the top: 0.7 s of CPU to import, unused by most runs
    q = np.quantile(np.sqrt(d2), 0.25, axis=-1) / stats.norm.ppf(0.625)
    a2 = np.where(q > 0, q**2, np.mean(d2, axis=-1)) / 6.0
    b2 = np.zeros_like(a2)
    active = np.ones(a2.shape, dtype=bool)
    for _ in range(MAX_ITERATIONS):
        v = np.maximum(x0 * a2[..., None] + x1 * b2[..., None], 1e-300)
        kept = d2 <= CLIP**2 * v
        w = np.where(kept, 1.0 / v**2, 0.0)
        new_a, new_b = _nnls2(x0, x1, d2 / CLIP_FACTOR, w)
        v_new = x0 * new_a[..., None] + x1 * new_b[..., None]
        a2, b2 = np.where(active, new_a, a2), np.where(active, new_b, b2)
        # settled: the variance model moved by less than 1e-6 (relative) at every difference (10-15 iterations)
        active &= ~np.all(np.abs(v_new - v) <= 1e-6 * v, axis=-1)
        if not active.any():
            break
    return a2, b2


def estimate_noise_model(residual: np.ndarray, amplitude: np.ndarray, freqs_hz) -> NoiseModel:
    """The noise model ``sigma_ij^2 = a_j^2 + (b_j / u_ij)^2`` fitted to a log residual's second differences.

    Parameters
    ----------
    residual : ndarray, shape (p, n)
        ``ln(|Z_model| / u)`` on lines where every channel is kept, in the order of ``freqs_hz``.
    amplitude : ndarray, shape (p, n)
        The measured amplitudes ``u`` at them (the floor ``b_j`` comes out in their units).
    freqs_hz : ndarray, shape (p,)

    For white noise of that model, ``d = r[i-1] - 2 r[i] + r[i+1]`` has variance
    ``6 a^2 + b^2 (1/u[i-1]^2 + 4/u[i]^2 + 1/u[i+1]^2)``: linear in ``(a_j^2, b_j^2)``, which are fitted per
    channel (:func:`_fit_channel`) within every evenly stepped band of three lines or more. Raises ValueError
    when no band has three lines.
    """
    r = np.asarray(residual, float)
    u = np.asarray(amplitude, float)
    bands = _bands(freqs_hz)
    if not bands:
        raise ValueError("the noise cannot be estimated (no band of three evenly stepped lines); configure it")
    d = _second_differences(r, bands)  # (m, n)
    x0, x1 = _design(u, bands)
    a2, b2 = _fit_model(d, x0, x1)
    sigma = np.sqrt(a2[None, :] + b2[None, :] / u**2)
    return NoiseModel(sigma, "estimated", np.sqrt(a2), np.sqrt(b2))


def differences_per_channel(freqs_hz) -> int:
    """Second differences each channel has along the evenly stepped bands of ``freqs_hz``."""
    return int(sum(b.size - 2 for b in _bands(freqs_hz)))


def one_level(noise, freqs_hz) -> bool:
    """Whether ``noise`` (a level, None, a :class:`NoiseModel` or :class:`Estimated`) judges a residual on the
    lines ``freqs_hz`` by one level for every value: a level or None, or a model to estimate from too few second
    differences per channel (a few windows of lines: a model per channel would fit a misfit)."""
    if isinstance(noise, Estimated):
        return differences_per_channel(freqs_hz) < MIN_DIFFERENCES
    return not isinstance(noise, NoiseModel)


def judged_by(noise, residual: np.ndarray, freqs_hz) -> NoiseModel:
    """The noise per line and channel that judges the log residual (p, n) when not :func:`one_level`: a measured
    model (coherence, records) with its level per channel checked against the residual (:func:`calibrate`), a
    configured one as it is, an :class:`Estimated` one fitted to the residual (:func:`estimate_noise_model`)."""
    r = np.asarray(residual, float)
    if isinstance(noise, Estimated):
        amplitude = np.asarray(noise.amplitude, float)
        if amplitude.shape != r.shape:
            raise ValueError(f"the noise model's amplitudes have shape {amplitude.shape}, the residual {r.shape}")
        return estimate_noise_model(r, amplitude, freqs_hz)
    return calibrate(noise, r, freqs_hz) if noise.source in ("coherence", "records") else noise


def _fit_model(d: np.ndarray, x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(a^2, b^2)`` per channel, shapes (..., n), from second differences ``d`` (..., m, n): a relative term and
    a floor per channel (:func:`_fit`) where each channel has at least :data:`MIN_DIFFERENCES` of them; else one
    relative level for every value (the clipped level of all of them, :func:`fe_core.inference.levels.estimate_noise`):
    two parameters a channel from a few windows of lines round the resonances would fit a misfit as noise, and
    a model fitted to few values makes its own test's statistic heavy-tailed."""
    m = d.shape[-2]
    if m >= MIN_DIFFERENCES:
        return _fit(np.swapaxes(d, -1, -2) ** 2, x0.T, x1.T)
    lead = d.shape[:-2]
    level = _clipped_level(d.reshape(-1, d.shape[-2] * d.shape[-1])).reshape(lead)
    a2 = np.broadcast_to((level**2)[..., None], lead + (d.shape[-1],)).copy()
    return a2, np.zeros_like(a2)


# -- the test ------------------------------------------------------------------------------------------------
def _null_draws(sigma: np.ndarray, u: np.ndarray, freqs_hz, n_fitted: int, draws: int) -> np.ndarray:
    """``sum e^2 / sigma_hat^2`` of white-noise residuals ``e = sigma z`` (fixed seed), the model estimated again
    from each draw; ``n_fitted`` values' squares left out (a fit takes about that many). In chunks of at most
    2 million values."""
    rng = np.random.default_rng(0)
    bands = _bands(freqs_hz)
    x0, x1 = _design(u, bands)
    out = []
    chunk = max(1, min(draws, 2_000_000 // sigma.size))
    for start in range(0, draws, chunk):
        k = min(chunk, draws - start)
        e = sigma * rng.standard_normal((k,) + sigma.shape)
        a2, b2 = _fit_model(_second_differences(e, bands), x0, x1)  # (k, n)
        s = np.sqrt(a2[:, None, :] + b2[:, None, :] / u**2)
        out.append(np.sum((e / s).reshape(k, -1)[:, int(n_fitted):] ** 2, axis=1))
    return np.concatenate(out)


@lru_cache(maxsize=16)
def _estimated_null(key: bytes, shape: tuple[int, int], u_key: bytes, freqs_key: bytes, n_fitted: int
                    ) -> np.ndarray:
    """Sorted statistics of :data:`NULL_DRAWS` white-noise residuals of an estimated model (cached per model)."""
    sigma = np.frombuffer(key).reshape(shape)
    u = np.frombuffer(u_key).reshape(shape)
    freqs = np.frombuffer(freqs_key)
    return np.sort(_null_draws(sigma, u, freqs, n_fitted, NULL_DRAWS))


def _tail(null: np.ndarray, T: float) -> float:
    """``P(T* >= T)`` from sorted null draws, ``(1 + #) / (1 + draws)``: the draws' own distribution, not a
    fitted one (a model re-estimated from few values makes the statistic heavy-tailed, and the moments of a
    few outlying draws would make any residual look like noise)."""
    return float((null.size - np.searchsorted(null, T, side="left") + 1) / (null.size + 1))


def _levels(d: np.ndarray) -> np.ndarray:
    """Per channel, the clipped level of second differences ``d`` (..., m, n) (as
    :func:`fe_core.inference.residual.estimate_noise`): the standard deviation of the values they come from."""
    rows = np.moveaxis(d, -1, -2)  # (..., n, m)
    return _clipped_level(rows.reshape(-1, rows.shape[-1])).reshape(rows.shape[:-1])


def calibrate(noise: "NoiseModel", residual: np.ndarray, freqs_hz) -> "NoiseModel":
    """A measured model (coherence, records) with its level per channel checked against a log residual (p, n):
    the scale ``c_j`` is the clipped level of the second differences of ``r / sigma`` along frequency (a misfit
    smooth in frequency adds little to them), so the measured shape per line is kept and a level the coherence
    misstates is not taken for structure: with hits of unequal force the H1 estimate's spread is larger than the
    coherence says (the hammer example's 10 hits of +-30 %: 4 % in variance, which 9,000 values call structure).
    Raises ValueError when no band has three lines."""
    bands = _bands(freqs_hz)
    if not bands:
        raise ValueError("the noise level cannot be checked (no band of three evenly stepped lines)")
    measured = noise.sigma if noise.scale is None else noise.sigma / noise.scale[None, :]
    c = _levels(_second_differences(np.asarray(residual, float) / measured, bands))
    return NoiseModel(measured * c[None, :], noise.source, noise.relative, noise.floor, noise.t_dof, c)


@lru_cache(maxsize=16)
def _calibrated_null(band_sizes: tuple[int, ...], shape: tuple[int, int], t_key: bytes | None, n_fitted: int
                     ) -> np.ndarray:
    """Sorted ``sum (w / c)^2`` of :data:`NULL_DRAWS` white residuals ``w`` (Student-t with the model's degrees of
    freedom, else normal; fixed seed) with their level per channel ``c`` estimated as :func:`calibrate` does."""
    rng = np.random.default_rng(0)
    t_dof = None if t_key is None else np.frombuffer(t_key).reshape(shape)
    starts = np.cumsum((0,) + band_sizes)
    bands = [np.arange(a, a + b) for a, b in zip(starts[:-1], band_sizes) if b >= 3]
    out = []
    chunk = max(1, min(NULL_DRAWS, 2_000_000 // int(np.prod(shape))))
    for start in range(0, NULL_DRAWS, chunk):
        k = min(chunk, NULL_DRAWS - start)
        if t_dof is None:
            w = rng.standard_normal((k,) + shape)
        else:
            w = rng.standard_normal((k,) + shape) / np.sqrt(rng.chisquare(np.broadcast_to(t_dof, (k,) + shape))
                                                           / t_dof)
        c = _levels(_second_differences(w, bands))  # (k, n)
        out.append(np.sum((w / c[:, None, :]).reshape(k, -1)[:, int(n_fitted):] ** 2, axis=1))
    return np.sort(np.concatenate(out))


#: Student-t degrees of freedom below which ``w^2`` has no variance (``nu <= 4``): such values are counted as
#: if they had this many (the test is then a little too ready to call noise structure, never the other way).
MIN_T_DOF = 4.5


def _t_moments(t_dof: np.ndarray, n_fitted: int) -> tuple[float, float]:
    """Mean and variance of ``sum w^2`` over values whose ``w`` is Student-t with ``t_dof`` degrees of freedom
    (``w^2`` is F(1, nu): mean ``nu / (nu - 2)``, variance ``2 nu^2 (nu - 1) / ((nu - 2)^2 (nu - 4))``), less the
    mean share of the ``n_fitted`` values a fit takes."""
    nu = np.maximum(np.asarray(t_dof, float).ravel(), MIN_T_DOF)
    m1 = nu / (nu - 2.0)
    v1 = 2.0 * nu**2 * (nu - 1.0) / ((nu - 2.0) ** 2 * (nu - 4.0))
    share = 1.0 - n_fitted / nu.size
    return float(m1.sum() * share), float(v1.sum() * share)


def noise_model_test(residual: np.ndarray, noise: NoiseModel, n_fitted: int, amplitude: np.ndarray | None = None,
                     freqs_hz=None) -> tuple[float, int, float]:
    """``(T, dof, p)``: ``T = sum (r / sigma)^2`` of the log residual ``r`` (p, n) against its noise model.

    A model known beforehand gives ``T`` chi-square with ``N - n_fitted`` degrees of freedom (configured), or,
    where ``sigma`` was itself estimated from the averages (coherence, records: ``t_dof``), a sum of squared
    Student-t values, tested against the scaled chi-square of its mean and variance; a measured model whose
    level was checked against this residual (:func:`calibrate`, ``freqs_hz`` needed) against white residuals
    whose level is estimated alike. A model estimated from this residual (``amplitude`` and ``freqs_hz``
    needed) is tested
    against white noise drawn from that same model and estimated again from each draw: ``p`` is the share of
    :data:`NULL_DRAWS` draws (fixed seed, cached per model) whose statistic is at least ``T`` (:func:`_tail`;
    the smallest p is ``1 / (NULL_DRAWS + 1)``).
    """
    from scipy import stats  # here, not at the top: 0.7 s of CPU to import, unused by most runs
    r = np.asarray(residual, float)
    w = r / noise.sigma
    T = float(np.sum(w**2))
    dof = r.size - int(n_fitted)
    if dof < 1:
        raise ValueError(f"{r.size} residuals cannot test a fit of {n_fitted} parameters")
    if noise.source != "estimated":
        if noise.scale is not None:  # the level was checked against this residual (:func:`calibrate`)
            sizes = tuple(int(b.size) for b in frequency_bands(freqs_hz))
            t_key = None if noise.t_dof is None else np.ascontiguousarray(noise.t_dof, float).tobytes()
            return T, dof, _tail(_calibrated_null(sizes, r.shape, t_key, int(n_fitted)), T)
        if noise.t_dof is None:
            return T, dof, float(stats.chi2.sf(T, dof))
        mean, var = _t_moments(np.asarray(noise.t_dof, float), int(n_fitted))
        c = var / (2.0 * mean)
        return T, dof, float(stats.chi2.sf(T / c, mean / c))
    sigma = np.ascontiguousarray(noise.sigma, float)
    u = np.ascontiguousarray(amplitude, float)
    f = np.ascontiguousarray(freqs_hz, float)
    return T, dof, _tail(_estimated_null(sigma.tobytes(), sigma.shape, u.tobytes(), f.tobytes(), int(n_fitted)), T)
