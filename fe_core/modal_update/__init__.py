"""Updating on measured modes (plain numpy/scipy): exact eigen-derivatives by Nelson's method
(:mod:`.nelson`), the paired frequency and shape residual with mode tracking (:mod:`.residual`), and the
local least-squares fit from several starts with Laplace intervals (:mod:`.fit`) and the closure by forward
selection of effects (:mod:`.closure`). The paper's MRGP loop over the modal residuals and the modal update's
own run of the fit are strategies (:mod:`strategies.modal_paper`, :mod:`strategies.modal_fit`), above this
package."""

from .fit import ModalFit, fit_modes, laplace_intervals
from .nelson import eigen_derivatives
from .residual import ModalResidual, identifiability

__all__ = ["eigen_derivatives", "ModalResidual", "identifiability", "ModalFit", "fit_modes", "laplace_intervals"]
