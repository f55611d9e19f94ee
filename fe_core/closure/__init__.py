"""Closing the loop: effects the model lacks, traced from the residual, added and fitted.

* :mod:`.effects`: the library of candidate effects (masses, springs, damage, damping, sensors) and the
  extended model's FRF;
* :mod:`.fits`: least-squares fits with and without an effect, screening, checks, scores and verdicts;
* :mod:`.selection`: forward selection of several effects, with moves and swaps;
* :mod:`.loop`: :func:`close_loop`, all of it in one call;
* :mod:`.jacobian`: the exact Jacobian of the extended model (alpha and the effects' values);
* :mod:`.intervals`: the Laplace intervals of alpha and the effects' values after a closure.

Residual statistics (noise level, chi-square test) live in :mod:`fe_core.inference.residual`, shared with
the strategies' check.
"""
