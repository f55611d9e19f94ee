"""Is an effect plausible in size? It must move a natural frequency in the band by more than the model's own error.

After the effect that explains most of a far-off residual, what is left is partly the model's own error: a coarse
mesh's modes a fraction of a per cent off, an element formulation or a parametrisation that differs a little from
the structure's. Any effect of the library, chosen from thousands of places, can take a share of that misfit out; on
issue 40's box arm a 0.75 g mass (0.004 % of the structure) and a spring to the ground were added so, and on the
tet10 plate with its 4 % mass a damaged patch of 3.6 % stiffness loss took 7 % of the residual left (17 % weighted by
the measured coherence), all of it within a few lines round one mode (a misfit of 3 % of ``ln|Z|`` at its peak,
about 0.03 % of its frequency). A claim about the structure should be one the model could not have made by its own
error: an effect added after the first must shift at least one natural frequency in the band by :data:`MIN_SHIFT`
or more. The first effect is not judged so: it is weighed against the alpha-only fit by the extended BIC on the
residual's effectively independent values (:mod:`.misfit`), and a model with no error of its own resolves effects
that shift its modes far less (the three-plate benchmark's 0.15 kg point mass far from nominal: 0.2 %, found with
0.5 % noise).

The shift is first order in the effect's terms, on the modes of the reduced model at the fit
(:class:`.reduced.ReducedModel`, M-orthonormal): ``d lambda_k = q_k^T (dK - lambda_k dM) q_k`` and
``df_k / f_k = d lambda_k / (2 lambda_k)``. Effects without stiffness or mass terms (damping, a sensor's gain) are
not judged so.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from .reduced import ReducedModel

__all__ = ["MIN_SHIFT", "frequency_shifts", "mark_negligible"]

log = logging.getLogger(__name__)

#: The least relative shift of a natural frequency in the band an added effect must give: half a per cent, about
#: what a shell or solid mesh converged to engineering accuracy is off (issue 40's box arm: its coarse deck's modes
#: against the 2x finer deck's). The dev cases' true effects (2-8 % of the mass, a mount) shift a mode by one to
#: several per cent; the effects fitted to the model's own error by well under a tenth of one
#: (docs/results/closure-far-effects.md).
MIN_SHIFT = 0.005


def frequency_shifts(rm: ReducedModel, alpha, item) -> np.ndarray | None:
    """Relative first-order shifts ``df / f`` of the reduced model's natural frequencies in the band (those up to
    the top line) at ``alpha`` from the effect ``item`` (:class:`fe_core.closure.effects.Applied`) at its values;
    None when the effect has no stiffness or mass term."""
    dK, dM, _, _, _ = rm.terms(item.effect, item.location, item.values, alpha)
    if dK is None and dM is None:
        return None
    mu, q = rm.modal(alpha)
    top = (2 * np.pi * rm.freqs_hz.max()) ** 2
    keep = (mu > 0) & (mu <= top)
    q, lam = q[:, keep], mu[keep]
    dlam = np.zeros(lam.size)
    if dK is not None:
        dlam += np.einsum("ik,ij,jk->k", q, dK, q)
    if dM is not None:
        dlam -= lam * np.einsum("ik,ij,jk->k", q, dM, q)
    return dlam / (2.0 * lam)


def mark_negligible(model, freqs_hz, base, checked: Sequence, min_shift: float = MIN_SHIFT) -> None:
    """Set ``negligible`` and ``largest_shift`` on each checked candidate (:class:`fe_core.closure.screening.Candidate`
    with its fit): negligible when its own effect, at its fitted values, shifts no natural frequency in the band by
    ``min_shift`` (on the reduced model at ``base``, the fit without it: one full FE evaluation for all)."""
    todo = [c for c in checked if c.fit is not None and _own(c) is not None]
    if not todo:
        return
    rm = ReducedModel(model, freqs_hz, base.alpha, base.applied)
    for c in todo:
        shifts = frequency_shifts(rm, base.alpha, _own(c))
        if shifts is None or shifts.size == 0:
            continue
        c.largest_shift = float(np.max(np.abs(shifts)))
        c.negligible = c.largest_shift < min_shift
        if c.negligible:
            log.info("%s at %s = %s: shifts no natural frequency in the band by %.1f %% or more (at most %.3f %%): "
                     "not plausible in size", c.effect, c.location, np.round(_own(c).values, 6), 100 * min_shift,
                     100 * c.largest_shift)


def _own(c):
    """The candidate's own effect among its fit's effects (the last one of its kind and place), or None."""
    for a in reversed(list(c.fit.applied)):
        if a.effect.kind == c.effect and a.location == c.location:
            return a
    return None
