"""Multi-response Gaussian process (MRGP) meta-model of Zhou & Tang, Section 2.2.

Plain numpy/scipy. The MRGP emulates all ``k`` response errors of the FE
model at once (72 = 6 sensors x 12 frequencies in the benchmark)::

    Y ~ GP(H(X) beta, Q (x) Sigma(X, X'))                     (Eq. 7)

``H = [1, x]`` (linear mean; constant or zero on request), ``Sigma`` the
isotropic squared-exponential kernel of Eq. (8) (or ARD: one length scale per
input) plus an optional nugget, ``Q`` (k x k) the covariance between
responses. Responses are standardised internally (they span decades); inputs
are used as given. Typical use::

    import numpy as np
    from mrgp_core import fit

    model = fit(X, Y, trainer="gradient", rng=np.random.default_rng(0))
    mean, var = model.predict(X_candidates)            # (w, k) each
    score = model.predicted_overall_error(X_candidates)  # (w,), Eq. (6b)

The traps, and what this package does about them:

* **Eq. (8) divides by 2l**, so ``l`` is a *squared* length scale; it is kept
  that way (scikit-learn's ``RBF(s)`` is ``l = s**2``).
* **Eq. (11) drops the inverses**; the GLS ``beta = (H^T Sigma^-1 H)^-1 H^T
  Sigma^-1 Y`` is used.
* **sigma_f is not identifiable** when ``Q`` is estimated: ``Q (x) sigma_f^2 R``
  is unchanged by ``sigma_f -> c sigma_f, Q -> Q / c^2``. The code fixes
  ``sigma_f = 1`` and lets ``Q`` carry every response's amplitude; the nugget
  is the ratio ``g = sigma_n^2 / sigma_f^2``. The trainers therefore search
  ``(l, g)`` (``l`` alone with a fixed nugget) instead of Table 1's
  ``(l, sigma_f)``; Table 1's ``l`` bounds, start and schedules are kept.
* **Q of Eq. (12) has rank <= r - q**, singular for the first iteration
  (r = 20 runs, q = 7, k = 72 responses), which makes Eq. (10) ``-inf``. ``Q``
  is shrunk toward its diagonal, ``Q_reg = (1 - lam) Q^ + lam diag(Q^)`` plus a
  1e-10 relative floor, with ``lam = k / (k + r - q)`` by default; this keeps
  each response's variance, so predictive variances do not depend on ``lam``.
  ``Sigma``'s diagonal is perturbed by a fixed ``jitter = 1e-8`` (relative to
  ``sigma_f^2 = 1``). The objective is the exact Eq. (10) at ``(beta^, Q_reg)``,
  and its analytic gradient is of that same function.
* **Table 1 swaps "upper" and "lower"**: ``l`` lies in ``(0, l~]`` with ``l~``
  the previous iteration's optimum (``fit(..., l_upper=l_prev)``).
* The (r k) x (r k) Kronecker product is never formed: everything comes from
  Cholesky factors of the r x r ``Sigma`` and the k x k ``Q_reg``, and
  prediction never forms the w x w posterior covariance.

Modules: :mod:`.kernels`, :mod:`.likelihood`, :mod:`.model`,
:mod:`.optimizers` (``"gradient"``, ``"sao"``, ``"pso"``); :mod:`.adaptive`
holds the pure pieces of the adaptive loop; :mod:`.reduced` emulates
thousands of responses through their leading principal directions
(``fit_reduced``: same ``predict`` and ``predicted_overall_error``, an r x r
``Q``).
"""

from .kernels import correlation, squared_distances
from .likelihood import (
    DEFAULT_JITTER,
    MEANS,
    Hyperparameters,
    ProfileLikelihood,
    profile,
    regularise_q,
    shrinkage_weight,
    standardise,
)
from .model import CRITERIA, MRGP, TrainingRecord, condition, default_bounds, fit, predicted_overall_error
from .optimizers import TRAINERS, Result, get_trainer
from .reduced import OutputBasis, ReducedMRGP, condition_reduced, fit_reduced, output_basis

__all__ = [
    "fit",
    "condition",
    "MRGP",
    "TrainingRecord",
    "Hyperparameters",
    "predicted_overall_error",
    "CRITERIA",
    "default_bounds",
    "ProfileLikelihood",
    "profile",
    "regularise_q",
    "shrinkage_weight",
    "standardise",
    "correlation",
    "squared_distances",
    "MEANS",
    "DEFAULT_JITTER",
    "TRAINERS",
    "get_trainer",
    "Result",
    "fit_reduced",
    "condition_reduced",
    "ReducedMRGP",
    "OutputBasis",
    "output_basis",
]
