"""Closing the loop: effects the model lacks, traced from the residual, added and fitted.

* :mod:`.effects`: the library of candidate effects (masses, springs, damage, damping, sensors) and the
  extended model's FRF;
* :mod:`.fits`: least-squares fits of alpha with and without effects, the alpha-only baseline;
* :mod:`.screening`: candidates screened by linearisation, then checked by full fits (moved if better);
* :mod:`.decisions`: scores, plausibility, the chosen effect, the verdict and the ranking;
* :mod:`.selection`: forward selection of several effects, with moves and swaps;
* :mod:`.loop`: :func:`close_loop`, all of it in one call;
* :mod:`.jacobian`: the exact Jacobian of the extended model (alpha and the effects' values);
* :mod:`.intervals`: the Laplace intervals of alpha and the effects' values after a closure.

Residual statistics (noise level, chi-square test) live in :mod:`fe_core.inference.residual`, shared with
the strategies' check.

The steps (each a plain function, so a flow can store and resume them one by one):

1. :func:`.fits.baseline`, :func:`.fits.fit_update` without an effect: the best stiffness factors alpha
   alone (least squares on the FE model from the earlier updated point), and
   :func:`fe_core.inference.residual.analyse_residual` of what remains.
2. :func:`.screening.screen`: every candidate (effect type x location) linearised at
   that point. With ``r`` the log residual and ``J_alpha`` its Jacobian, a
   candidate with sensitivity ``j`` (from :class:`fe_core.closure.effects.LinearisedResponse`,
   one field solve for all candidates) explains
   ``||P r||^2 - min_d ||P (r + j d)||^2`` of the residual sum of squares,
   where ``P`` projects out ``J_alpha`` (alpha is re-fitted with the effect)
   and ``d`` respects the effect's bounds (a mass cannot be negative).
3. :func:`.screening.check`: full FE least squares on ``[alpha, effect]`` for the best
   few candidates of each type, started from the updated alpha and the
   linear estimate; a searched location (a node) is then moved to a
   neighbour while the linearised prediction at the fitted point says that
   helps and the full fit confirms it.
4. :func:`.decisions.decide`: scores charge for parameters. ``BIC = N ln(RSS/N) +
   k ln N`` and the extended BIC of Chen & Chen (2008) adds ``2 ln L`` for an
   effect searched over ``L`` locations (choosing the best of 585 nodes is a
   fit too). An effect is added only if the residual before it is
   structure (chi-square test) and its extended BIC beats the model without it.

5. Forward selection (:func:`fe_core.closure.selection.forward_select`): steps 2-4
   repeat with the effects added so far in the model, all of them refitted
   together with alpha at every step, while the residual is structure and an
   effect improves the extended BIC (up to ``max_effects``); with two or more
   effects, each is swapped for the best alternative in its place while that
   improves the extended BIC. A fit that ends on an effect's plausibility
   bound (:meth:`fe_core.closure.effects.Effect.bounds_at`) is reported implausible
   and never added.
6. The verdict (:func:`.decisions.verdict`): ``noise`` (the residual before was noise, nothing to add),
   ``explained`` (effects were added, the residual after them is noise and
   each effect's kind holds at least 95 % of the evidence among the kinds
   checked in its place, its location pinned down), ``ambiguous`` (noise
   after, but a rival kind or a distant location fits about as well: listed,
   not a finding), ``partly
   explained`` (structure remains: what was added and the best candidates
   are candidates, not findings).

The candidates' ranking is by extended BIC for checked candidates, then by
the extended BIC predicted by the linearisation.
"""

# Issue 28: every closure fit on the growing reduced model (:mod:`.fast`), by default; ``MRGP_CLOSURE_FAST=0``
# (also in the flow's worker processes, which inherit it) keeps the plain path: a full Krylov space per evaluation.
from .fast import by_default as _by_default, install as _install  # noqa: E402

if _by_default():
    _install()
