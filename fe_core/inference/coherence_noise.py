"""The random error of an averaged H1 FRF from its ordinary coherence and number of averages.

Bendat & Piersol (Random Data, 4th ed., section 9.2.4; Engineering Applications of Correlation and Spectral
Analysis, table 9.6) give the normalised random error of the gain and the standard deviation of the phase of
an H1 frequency-response estimate from ``n`` averages with ordinary coherence ``gamma^2``::

    eps[|H|] = sigma[|H|] / |H| = sqrt(1 - gamma^2) / (|gamma| sqrt(2 n))
    sigma[phase] = eps[|H|]                      (radians)

Because ``sigma[ln |H|] = sigma[|H|] / |H|`` to first order, the same number is the standard deviation of
``ln |H|`` and of the phase. It is the standard deviation of each of the real and imaginary parts of the
relative error ``(H_hat - H) / H``: with noise on the response only and the same force spectrum in every
average, ``H_hat - H`` is complex Gaussian with variance ``|H|^2 (1 - gamma^2) / (gamma^2 n)`` split evenly
between the two parts, so the formula is then exact to first order in ``eps`` (checked by Monte Carlo in
``tests/fe_core/test_coherence_noise.py``). Bendat & Piersol advise it for ``eps`` up to about 0.2.

A file holds the *estimated* coherence of the same ``n`` averages, which is biased upwards: with response
noise ``E[1 - gamma_hat^2] = (1 - gamma^2) (n - 1) / n``, and the formula at ``gamma_hat^2`` gives a spread
``sqrt((n - 1) / n)`` too small (5 % at 10 averages, measured by the Monte Carlo). H1 is the least-squares
fit of one complex number to ``n`` pairs (force, response), whose residual sum of squares is
``S_xx (1 - gamma_hat^2)`` with ``n - 1`` degrees of freedom; the unbiased variance estimate that follows
is the formula with ``n - 1`` in place of ``n``, which is what this function uses by default
(``coherence_estimated=True``); ``False`` gives Bendat & Piersol's formula for a known coherence.

A residual divided by this estimated standard deviation is not standard normal: given the forces, the
real (or imaginary) part of ``(H_hat - H) / H`` over ``sigma_hat`` is Student-t with
``nu = 2 (n - 1)`` degrees of freedom (:func:`t_degrees_of_freedom`; the residual sum of squares is
independent of the fit), whose variance is ``nu / (nu - 2)``: 4/3 at 5 averages, 9/8 at 10, infinite at 2.
A chi-square test of standardised residuals must use that (or the t distribution), else it calls noise
structure; the Monte Carlo checks it, and on the raw-record example (5 hits) the squared standardised
residuals at the true parameters average 1.34.

Pure numpy: the per-line, per-channel noise model of the residual (and its tests) uses it with the coherence
and averages of :class:`tasks.io.measured.MeasuredFRF`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["frf_random_error", "t_degrees_of_freedom"]


def frf_random_error(coherence, averages, *, coherence_estimated: bool = True):
    """Standard deviation of ``ln|H|`` and of the phase (rad) of an averaged H1 estimate, per line and channel.

    Parameters
    ----------
    coherence : array_like, shape (p, n)
        Ordinary coherence ``gamma^2`` in [0, 1] per frequency line ``p`` and channel ``n`` (any shape).
    averages : array_like, shape (n,) or (p, n) or scalar, int
        Number of averages (hits) behind each value, broadcast against ``coherence`` (a per-channel vector
        along the last axis). At least 1.
    coherence_estimated : bool
        True (default): ``coherence`` was estimated from the same ``averages`` (what a measured file
        holds): ``n - 1`` degrees of freedom. False: the true coherence, Bendat & Piersol's ``n``.

    Returns
    -------
    ndarray, shape of ``coherence``, float
        ``sqrt(1 - gamma^2) / (sqrt(gamma^2) sqrt(2 d))`` with ``d = n - 1`` (estimated coherence) or
        ``d = n``: the standard deviation of ``ln|H|`` (relative amplitude error) and of the phase in
        radians; ``inf`` where the coherence is 0 (the response holds no trace of the force); ``nan`` where
        an estimated coherence comes from ``n = 1`` average (it is 1 by construction and says nothing
        about the noise).

    Raises
    ------
    ValueError
        For coherence outside [0, 1] or not finite, averages below 1 or not whole, or shapes that do not
        broadcast.
    """
    gamma2 = np.asarray(coherence, dtype=float)
    n = np.asarray(averages, dtype=float)
    if not np.all(np.isfinite(gamma2)) or np.any((gamma2 < 0) | (gamma2 > 1)):
        raise ValueError("coherence must lie in [0, 1]")
    if not np.all(np.isfinite(n)) or np.any(n < 1) or np.any(n != np.round(n)):
        raise ValueError("averages must be whole numbers >= 1")
    gamma2, n = np.broadcast_arrays(gamma2, n)
    dof = n - 1.0 if coherence_estimated else n
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.sqrt(1.0 - gamma2) / (np.sqrt(gamma2) * np.sqrt(2.0 * dof))
    return np.where(dof == 0, np.nan, sigma)


def t_degrees_of_freedom(averages):
    """Degrees of freedom ``2 (n - 1)`` of a residual standardised by :func:`frf_random_error` (estimated coherence).

    Parameters
    ----------
    averages : array_like, int, any shape
        Number of averages ``n`` (>= 1).

    Returns
    -------
    ndarray, float, shape of ``averages``
        ``nu = 2 (n - 1)``: the real and the imaginary part of a standardised residual are each Student-t with
        ``nu`` degrees of freedom, variance ``nu / (nu - 2)`` (finite for ``n >= 3``); 0 for ``n = 1``.
    """
    n = np.asarray(averages, dtype=float)
    if not np.all(np.isfinite(n)) or np.any(n < 1) or np.any(n != np.round(n)):
        raise ValueError("averages must be whole numbers >= 1")
    return 2.0 * (n - 1.0)
