"""Which parameters can the sensors see? Correlation and sensitivity of FRF amplitudes.

Two views of the same question (Zhou & Tang, Section 3.5):

:func:`pearson_correlation`
    Eq. (16): the Pearson coefficient of each parameter with each response
    over a Monte Carlo sample, ``cov(alpha_k, Z_ij) / (sigma_alpha_k sigma_Z_ij)``.
    Global (over the whole sampled box) but only linear and one parameter
    at a time.
:func:`log_amplitude_jacobian` and :func:`identifiability`
    The normalised sensitivity ``d log|Z| / d alpha`` at one parameter point
    (exact derivative of the FE model by the adjoint of the dynamic
    stiffness, on a Krylov space carrying both sides) and the singular values of that matrix. This is local but sees
    combinations: a parameter whose column is small, or that moves the
    responses the same way as another parameter, lies along a small singular
    value and cannot be pinned down from these sensors and frequencies.

``log|Z|`` is used because the updating error is the relative residual
``(|Z| - u) / u``, whose derivative at the solution is ``d log|Z| / d alpha``;
``alpha`` is itself a relative stiffness change, so the matrix has no units.

Plain numpy/scipy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import recycle
from .frf import hz_to_rad
from .frf_derivatives import Direction, direct_frf_derivatives, krylov_frf_derivatives
from ..model import ParametricModel

__all__ = [
    "pearson_correlation",
    "frf_jacobian",
    "log_amplitude_jacobian",
    "segment_directions",
    "JACOBIAN_METHODS",
    "identifiability",
    "Identifiability",
]


def pearson_correlation(X, Y) -> np.ndarray:
    """Pearson correlation of every column of ``X`` with every column of ``Y`` (Eq. 16).

    Parameters
    ----------
    X : array_like, shape (N, m)
        Samples of the inputs (one column per parameter).
    Y : array_like, shape (N, k)
        Samples of the responses (one column per response).

    Returns
    -------
    ndarray, shape (m, k)
        ``rho[a, b] = cov(X[:, a], Y[:, b]) / (std(X[:, a]) std(Y[:, b]))``.
        NaN where either column is constant (the coefficient is undefined).

    Raises
    ------
    ValueError
        If the row counts differ, there are fewer than 2 rows, or a value is
        not finite.
    """
    X = np.asarray(X, dtype=float)
    Y = np.asarray(Y, dtype=float)
    if X.ndim == 1:
        X = X[:, None]
    if Y.ndim == 1:
        Y = Y[:, None]
    if X.ndim != 2 or Y.ndim != 2:
        raise ValueError(f"X and Y must be 2-D (samples x variables), got shapes {X.shape} and {Y.shape}")
    if X.shape[0] != Y.shape[0]:
        raise ValueError(f"X has {X.shape[0]} samples but Y has {Y.shape[0]}")
    if X.shape[0] < 2:
        raise ValueError(f"a correlation needs at least 2 samples, got {X.shape[0]}")
    for name, A in (("X", X), ("Y", Y)):
        bad = ~np.isfinite(A)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise ValueError(f"{name}[{row}, {col}] = {A[row, col]} is not finite; drop failed samples first")
    # Centre and scale each column to unit norm (two-pass, so large offsets cost no precision).
    Xc = X - X.mean(axis=0)
    Yc = Y - Y.mean(axis=0)
    nx = np.linalg.norm(Xc, axis=0)
    ny = np.linalg.norm(Yc, axis=0)
    # A column is constant when its spread is at round-off level of its magnitude.
    tiny_x = nx <= 1e-14 * np.sqrt(X.shape[0]) * np.maximum(np.abs(X).max(axis=0), np.finfo(float).tiny)
    tiny_y = ny <= 1e-14 * np.sqrt(Y.shape[0]) * np.maximum(np.abs(Y).max(axis=0), np.finfo(float).tiny)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = (Xc / np.where(tiny_x, 1.0, nx)).T @ (Yc / np.where(tiny_y, 1.0, ny))
    rho[tiny_x, :] = np.nan
    rho[:, tiny_y] = np.nan
    return np.clip(rho, -1.0, 1.0)  # round-off can step just past +-1; NaN stays NaN


#: Ways :func:`frf_jacobian` computes the derivative: ``"krylov"`` (projection, the default) or
#: ``"direct"`` (one complex sparse LU per frequency, the reference).
JACOBIAN_METHODS = ("krylov", "direct")


def segment_directions(model: ParametricModel) -> list:
    """The derivative directions of the parameter vector, as :class:`fe_core.solvers.frf_derivatives.Direction` (cached).

    ``dK / dalpha_i = K_i`` for every segment, then ``dM / dgamma_j = M_j`` for every
    segment whose mass is updated (:attr:`ParametricModel.mass_parameters`), each on
    its own entries (:meth:`fe_core.assembly.SegmentedMatrix.own`), so a product costs the segment's entries.
    """
    cached = model.__dict__.get("_segment_directions")
    if cached is None:
        cached = []
        for i in range(model.n_segments):
            cached.append(Direction(stiffness=model.stiffness_segments.own(i)))
        for j in model.mass_parameters:
            cached.append(Direction(mass=model.mass_segments.own(int(j))))
        model.__dict__["_segment_directions"] = cached
    return cached


def frf_jacobian(model: ParametricModel, alpha, freqs_hz, method: str = "krylov",
                 return_info: bool = False, channels=None, space: dict | None = None):
    """The receptance at the sensors and its exact derivative with respect to the parameters.

    The dynamic stiffness ``D(w) = K(alpha) - w^2 M(gamma) + j w (a M(gamma) + b K(alpha))``
    depends on ``alpha_i`` through ``dD/dalpha_i = (1 + j w b) K_i`` and on an updated mass
    factor through ``dD/dgamma_i = (-w^2 + j w a) M_i``, so with ``h = D^-1 F`` (the response
    to the model's load) and ``g_s = D^-1 l_s`` (the adjoint for sensor s, ``l_s`` its output
    vector; D is complex symmetric)::

        dZ_s / dalpha_i = -(1 + j w b) g_s^T K_i h,    dZ_s / dgamma_i = -(-w^2 + j w a) g_s^T M_i h

    ``method="krylov"`` (default) evaluates this on one block Krylov space
    carrying both h and the g_s (:func:`fe_core.solvers.frf_derivatives.krylov_frf_derivatives`:
    one real factorisation of K, the space grown until Z and dZ stop changing
    to 1e-8; about 2.5 Krylov FRFs of time on the benchmark); ``"direct"``
    solves one complex sparse LU per frequency with 1 + n_sensors right-hand
    sides (the reference; about 25 Krylov FRFs). They agree to about 1e-9 of
    each frequency's largest derivative.

    Parameters
    ----------
    model : ParametricModel
    alpha : array_like, shape (n_parameters,)
        The parameter vector (:meth:`ParametricModel.factors`): alpha, then the updated gammas
        when the model has any.
    freqs_hz : array_like, shape (p,), Hz
    method : {"krylov", "direct"}
    return_info : bool
        Also return the :class:`fe_core.solvers.frf_derivatives.DerivativeInfo` of a
        Krylov evaluation (None for ``"direct"``).
    channels : (responses, references), optional
        As in :meth:`ParametricModel.parameter_frf`: the (sensor, excitation) channels, one space
        for all their references' loads; None = every sensor under the model's load.
    space : dict, optional
        Receives the converged Krylov space of a ``"krylov"`` evaluation (``basis``, n x d, and ``seeded``), for
        a global reduced basis (:mod:`fe_core.solvers.reduced_basis`).

    Returns
    -------
    Z : ndarray, shape (p, n_sensors) or (p, n_channels), complex, m/N
        Same as ``model.parameter_frf(alpha, freqs_hz, channels)`` (to its 1e-9).
    dZ : ndarray, shape (p, n_sensors or n_channels, n_parameters), complex, m/N per unit parameter
    """
    if method not in JACOBIAN_METHODS:
        raise ValueError(f"unknown Jacobian method {method!r}; choose one of {JACOBIAN_METHODS}")
    if getattr(model, "exact_jacobians", True) is False:  # a black-box solver: forward differences (its own)
        if return_info:
            raise ValueError("a black-box model's Jacobian is a forward difference: no derivative info")
        return model.frf_jacobian(alpha, freqs_hz, channels=channels)
    alpha, gamma = model.factors(alpha)
    freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    if freqs.ndim != 1 or freqs.size == 0 or np.any(~np.isfinite(freqs)) or np.any(freqs <= 0):
        raise ValueError(f"frequencies must be a non-empty 1-D array of positive values in Hz, got {freqs_hz!r}")
    K = model.stiffness(alpha)
    M = model.mass(gamma)
    a, b = model.damping
    if channels is None:
        loads, responses, column = model.combined_load(), slice(None), 0
    else:
        loads, responses, column = model.channel_loads(*channels)
    args = (K, M, a, b, loads, model.outputs, segment_directions(model), hz_to_rad(freqs))
    info = None
    if method == "krylov":  # a large model's space starts from its last FE run's (fe_core.solvers.recycle)
        keep = {} if recycle.active(model) or space is not None else None
        point = np.concatenate([np.ravel(alpha), np.ravel(gamma if gamma is not None else [])])
        Z, dZ, info = krylov_frf_derivatives(*args, return_info=True, seed=recycle.take(model, point), keep=keep)
        if keep is not None:
            if space is not None:
                space.update(keep)
            recycle.store(model, keep, point)
    else:
        Z, dZ = direct_frf_derivatives(*args)
    Z, dZ = Z[:, responses, column], dZ[:, responses, column, :]
    return (Z, dZ, info) if return_info else (Z, dZ)


def log_amplitude_jacobian(model: ParametricModel, alpha, freqs_hz, method: str = "krylov",
                           return_frf: bool = False, channels=None):
    """Normalised sensitivity ``d log|Z_fs| / d alpha_i`` of the FRF amplitudes.

    Parameters
    ----------
    model, alpha, freqs_hz, method
        As in :func:`frf_jacobian`.
    return_frf : bool
        Also return the receptance ``Z`` (shape (p, n_sensors)) it was computed
        with: the same FRF as ``model.frf`` (to 1e-9), for free.
    channels : (responses, references), optional
        As in :func:`frf_jacobian`: (sensor, excitation) channels, several references stacked (roving
        hammer, MIMO); then the rows are frequency-major with channels fastest.

    Returns
    -------
    ndarray, shape (p * n_sensors, m)
        Rows frequency-major with sensors fastest (the layout of Eq. 5), one
        column per parameter; dimensionless.
    """
    Z, dZ = frf_jacobian(model, alpha, freqs_hz, method, channels=channels)
    J = np.real(dZ / Z[:, :, None])  # d log|Z| = Re(dZ / Z)
    J = J.reshape(-1, J.shape[-1])
    return (J, Z) if return_frf else J


@dataclass(frozen=True)
class Identifiability:
    """What a sensitivity matrix says about which parameters can be identified.

    Attributes
    ----------
    singular_values : ndarray, shape (m,)
        Of the normalised sensitivity matrix, descending.
    directions : ndarray, shape (m, m)
        ``directions[j]`` is the unit parameter combination (right singular
        vector) belonging to ``singular_values[j]``, sign fixed so its largest
        entry is positive.
    column_norms : ndarray, shape (m,)
        Sensitivity of the responses to each parameter alone.
    std : ndarray, shape (m,)
        Linearised standard deviation of each parameter estimate when every
        amplitude carries relative noise ``noise``:
        ``noise * sqrt(diag((J^T J)^-1))`` (inf for a rank-deficient J).
    direction_std : ndarray, shape (m,)
        ``noise / singular_values``: the same for each combination.
    identifiable : ndarray of bool, shape (m,)
        ``std <= tolerance``.
    noise, tolerance : float
    names : list of str
    """

    singular_values: np.ndarray
    directions: np.ndarray
    column_norms: np.ndarray
    std: np.ndarray
    direction_std: np.ndarray
    identifiable: np.ndarray
    noise: float
    tolerance: float
    names: list

    @property
    def condition_number(self) -> float:
        s = self.singular_values
        return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")

    def describe_direction(self, j: int, threshold: float = 0.3) -> str:
        """A combination as text, e.g. ``"0.71 alpha_3 - 0.69 alpha_4"`` (entries above ``threshold``)."""
        v = self.directions[j]
        order = np.argsort(-np.abs(v))
        terms = [(v[i], self.names[i]) for i in order if abs(v[i]) >= threshold] or [(v[order[0]], self.names[order[0]])]
        text = ""
        for k, (c, name) in enumerate(terms):
            sign = "-" if c < 0 else ("+" if k else "")
            text += (f" {sign} " if k else sign) + f"{abs(c):.2f} {name}"
        return text.strip()

    def summary_lines(self) -> list[str]:
        """Plain-language verdicts, one line per parameter, then the weakest combinations."""
        lines = []
        for name, s, c, ok in zip(self.names, self.std, self.column_norms, self.identifiable):
            verdict = "can be pinned down" if ok else "can NOT be pinned down"
            lines.append(f"{name}: {verdict} (+/- {s:.3g} at {self.noise:.2%} amplitude noise; "
                         f"sensitivity norm {c:.3g})")
        for j in range(len(self.singular_values)):
            if self.direction_std[j] > self.tolerance:
                lines.append(f"weak combination {self.describe_direction(j)}: singular value "
                             f"{self.singular_values[j]:.3g}, +/- {self.direction_std[j]:.3g}")
        return lines


def identifiability(J, names=None, noise: float = 0.01, tolerance: float = 0.05) -> Identifiability:
    """Singular values and parameter verdicts of a normalised sensitivity matrix.

    Parameters
    ----------
    J : array_like, shape (k, m)
        ``d log|Z| / d alpha`` (rows responses, columns parameters).
    names : list of str, optional
        Parameter names; ``alpha_1 ...`` by default.
    noise : float
        Relative amplitude noise, e.g. 0.01 = 1 %, assumed independent per response.
    tolerance : float
        Largest linearised standard deviation (in units of alpha) that still
        counts as "pinned down".

    Returns
    -------
    Identifiability
    """
    J = np.asarray(J, dtype=float)
    if J.ndim != 2 or J.shape[0] < 1 or J.shape[1] < 1:
        raise ValueError(f"J must be a 2-D matrix (responses x parameters), got shape {J.shape}")
    if not np.all(np.isfinite(J)):
        raise ValueError("J has non-finite entries")
    if not noise > 0 or not tolerance > 0:
        raise ValueError(f"noise and tolerance must be positive, got {noise} and {tolerance}")
    m = J.shape[1]
    names = list(names) if names is not None else [f"alpha_{i + 1}" for i in range(m)]
    if len(names) != m:
        raise ValueError(f"{len(names)} names for {m} parameters")
    _, s, Vt = np.linalg.svd(J, full_matrices=False)
    if s.size < m:  # fewer responses than parameters: the missing singular values are zero
        s = np.concatenate([s, np.zeros(m - s.size)])
        Vt = np.linalg.svd(J, full_matrices=True)[2]
    signs = np.sign(Vt[np.arange(m), np.argmax(np.abs(Vt), axis=1)])
    Vt = Vt * signs[:, None]
    rank_tol = s[0] * max(J.shape) * np.finfo(float).eps if s[0] > 0 else 0.0
    full = s > rank_tol
    # diag((J^T J)^-1) = sum_j V[i, j]^2 / s_j^2: a parameter with any weight on a null direction is unbounded.
    V2 = Vt.T**2
    finite_part = (V2[:, full] / s[full] ** 2).sum(axis=1)
    on_null = (V2[:, ~full] > 1e-24).any(axis=1)
    std = np.where(on_null, np.inf, noise * np.sqrt(finite_part))
    direction_std = np.full(m, np.inf)
    direction_std[full] = noise / s[full]
    return Identifiability(
        singular_values=s,
        directions=Vt,
        column_norms=np.linalg.norm(J, axis=0),
        std=std,
        direction_std=direction_std,
        identifiable=std <= tolerance,
        noise=float(noise),
        tolerance=float(tolerance),
        names=names,
    )
