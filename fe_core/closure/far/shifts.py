"""How far each mode of the model is from the data: the residual as per-mode frequency shifts.

A model with no effect missing but its own error (mesh, geometry, parametrisation) leaves, after its factors are
fitted, each mode a little off in frequency: the residual in ``ln|Z|`` is then, to first order, a sum of the
derivatives of ``ln|Z|`` along each mode's frequency. :func:`mode_shifts` fits those per-mode shifts (relative,
``d omega_r / omega_r``) to the residual by weighted nonlinear least squares on the reduced model at the fit
(:class:`.reduced.ReducedModel`; a shift moves one eigenvalue, its vector and the damping kept) and says how much
of the misfit beyond the noise they take out and how large the largest is.

The closure's size rule (:data:`.plausible.MIN_SHIFT`) holds half a per cent of a natural frequency for the model's
own error: an effect that shifts no mode by that much cannot be told from it. The same bar read the other way: a
misfit that per-mode shifts all within it take out is what the model's own error would give.

That bar is one number for every model; a model's own error is its own. Where the model can be refined (a mesh of
ten-node tetrahedra or eight-node hexahedra of moderate size, :func:`fe_core.model_error.floor_of`), the bar is the misfit the model leaves
against its own refined mesh at the fit (``floor``, noise-free, factors refitted) times :data:`FLOOR_FACTOR`: the
misfit beyond the noise is within the model's own error when it is at most that. :data:`FLOOR_FACTOR` was set on the
fourth held-out set (session 22's study, docs/results/held-out.md: its data on a mesh of half the model's size, clean
cases' misfits 0.75-1.15 times their floor, effect cases' 1.8 times and more) and is judged on the eleventh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .misfit import smooth_misfit
from .plausible import MIN_SHIFT

__all__ = ["ModeShifts", "mode_shifts", "own_error", "unclaimed", "FLOOR_FACTOR"]

#: The misfit beyond the noise a model may leave and still be within its own error, as a multiple of what it leaves
#: against its own refined mesh (the module docstring).
FLOOR_FACTOR = 1.4


@dataclass
class ModeShifts:
    """Per-mode relative frequency shifts fitted to a residual (model minus data in ``ln|Z|``).

    ``frequencies_hz``: the model's modes in the band; ``shifts``: the relative change of each that the model
    needs to meet the data (positive: the data's mode is higher); ``before`` and ``after``: the misfit beyond the
    noise (:func:`.misfit.smooth_misfit`) of the residual and of what the shifts leave (to first order)."""

    frequencies_hz: np.ndarray
    shifts: np.ndarray
    before: float
    after: float
    #: The rms of ``ln|Z|`` that one mode ``bar`` off leaves, averaged over the modes in the band
    #: (``sqrt(mean_r mean(d_r^2))``): what an effect the size rule just accepts (one that shifts a mode by the bar)
    #: would leave.
    single: float = float("nan")
    #: The misfit (rms of ``ln|Z|``) the model leaves against its own refined mesh at the fit, when measured
    #: (:func:`fe_core.model_error.floor_of`): the bar is then :data:`FLOOR_FACTOR` times it, not ``single``.
    floor: float = float("nan")

    @property
    def bar(self) -> float:
        """The misfit beyond the noise the model's own error may leave: :data:`FLOOR_FACTOR` times the refined
        mesh's floor where it was measured, else what one mode off by the size rule's bar would leave."""
        return FLOOR_FACTOR * self.floor if np.isfinite(self.floor) else self.single

    @property
    def largest(self) -> float:
        return float(np.max(np.abs(self.shifts))) if self.shifts.size else 0.0

    @property
    def within(self) -> bool:
        """Whether the misfit beyond the noise is at most :attr:`bar` (what the model leaves against its refined mesh,
        times :data:`FLOOR_FACTOR`, or what one mode off by the size rule's bar would leave): no effect of a size the
        closure would accept hides in it (it is the model's own error, or noise)."""
        return bool(self.before <= self.bar)

    def reason(self) -> str:
        modes = ("the band's only mode" if self.shifts.size == 1 else
                 f"one of the band's {self.shifts.size} modes")
        if np.isfinite(self.floor):
            what = (f"{FLOOR_FACTOR:g} times what the model leaves against its own refined mesh "
                    f"({self.bar:.2%}; the mesh's floor {self.floor:.2%})")
        else:
            what = (f"what {modes} {MIN_SHIFT:.1%} off in frequency would leave ({self.single:.2%}, the size rule's "
                    "bar)")
        return (f"the misfit beyond the noise ({self.before:.2%} rms of ln|Z|) is "
                f"{'at most' if self.within else 'more than'} {what}"
                + (": the model's own error, no effect of that size hides in it" if self.within else ""))

    @property
    def taken(self) -> float:
        """Share of the sum of squares beyond the noise that the shifts take out."""
        return 1.0 - (self.after / self.before) ** 2 if self.before > 0 else 1.0

    def to_dict(self) -> dict:
        return {"within": self.within, "reason": self.reason(),
                "frequencies_hz": self.frequencies_hz.tolist(), "shifts": self.shifts.tolist(),
                "largest": self.largest, "before": self.before, "after": self.after, "taken": self.taken,
                "single": self.single, "floor": None if not np.isfinite(self.floor) else self.floor,
                "bar": self.bar}


def mode_shifts(rm, alpha, amplitude, sigma, bar: float = MIN_SHIFT) -> ModeShifts:
    """The per-mode frequency shifts that best explain the residual of ``rm`` (a :class:`.reduced.ReducedModel` at
    ``alpha``, effects included) against ``amplitude`` (p, n_s), weighed by the noise ``sigma`` (a level or
    per-value levels): a nonlinear least-squares fit (a shift of a half-power bandwidth is far from first order),
    the modes' vectors and the damping held."""
    u = np.asarray(amplitude, float)
    s = np.broadcast_to(np.asarray(sigma, float), u.shape)
    mu, q = rm.modal(alpha)
    f = np.sqrt(np.maximum(mu, 0.0)) / (2 * np.pi)
    band = np.flatnonzero((mu > 0) & (f >= rm.freqs_hz.min()) & (f <= rm.freqs_hz.max()))
    # each mode in the band its own shift; the modes below and above it one common shift each (their quasi-static
    # share of the response: held, a stiffer model's modes above the band bent the last ones' shifts by 3 x)
    groups = [np.array([r]) for r in band] + [g for g in (np.flatnonzero((mu > 0) & (f < rm.freqs_hz.min())),
                                                         np.flatnonzero(f > rm.freqs_hz.max())) if g.size]
    w = rm.omegas[:, None]
    left = rm.left @ q                                   # (n_s, d)
    right = q.T @ rm.right                               # (d,)
    c = (1.0 + 1j * w * rm.b)                            # (p, 1)
    m = -(w**2 - 1j * w * rm.a)
    log_gain = np.log1p(rm.gain)[None, :]
    weight = 1.0 / s

    def response(x):
        lam = mu.copy()
        for g, xi in zip(groups, x):
            lam[g] = mu[g] * np.exp(2.0 * xi)
        g_ = 1.0 / (c * lam[None, :] + m)                # (p, d)
        return lam, g_, (g_ * right[None, :]) @ left.T   # Z: (p, n_s)

    def residual(x):
        _, _, Z = response(x)
        return ((np.log(np.abs(Z)) + log_gain - np.log(u)) * weight).ravel()

    def jacobian(x):
        lam, g_, Z = response(x)
        cols = []
        for g in groups:   # d Z / d ln omega_r = -2 lam_r c g_r^2 right_r left_r, summed over the group
            v = -2.0 * lam[g][None, :] * c * g_[:, g] ** 2 * right[g][None, :]     # (p, k)
            dZ = v @ left[:, g].T                                                 # (p, n_s)
            cols.append((np.real(dZ / Z) * weight).ravel())
        return np.column_stack(cols)

    lnZ0 = np.log(np.abs(response(np.zeros(len(groups)))[2]))
    r0 = lnZ0 + log_gain - np.log(u)                     # the residual as it is
    each = []
    for k in range(band.size):
        x = np.zeros(len(groups))
        x[k] = np.log1p(bar)
        each.append(float(np.mean((np.log(np.abs(response(x)[2])) - lnZ0) ** 2)))
    single = float(np.sqrt(np.mean(each))) if each else float("nan")
    if not band.size:
        return ModeShifts(f[band], np.zeros(0), smooth_misfit(r0, s), smooth_misfit(r0, s), single)
    # shifts within a factor of two: a mode the data do not show (held-out hd04) would run off without bound
    sol = least_squares(residual, np.zeros(len(groups)), jac=jacobian, method="trf", xtol=1e-10, ftol=1e-12,
                        bounds=(-np.log(2.0), np.log(2.0)))
    left_over = sol.fun / weight.ravel()
    return ModeShifts(f[band], np.expm1(sol.x[:band.size]), smooth_misfit(r0, s),
                      smooth_misfit(left_over.reshape(u.shape), s), single)


def own_error(model, freqs_hz, amplitude, fit, sigma, floor: float | None = None) -> ModeShifts:
    """:func:`mode_shifts` of ``fit`` (alpha and its effects) on the reduced model at it: is its misfit the model's
    own error (:attr:`ModeShifts.within`)? ``floor``: the model's misfit against its own refined mesh at the fit
    (:attr:`fe_core.model_error.MeshFloor.rms`), when measured."""
    from .reduced import ReducedModel

    rm = ReducedModel(model, freqs_hz, fit.alpha, fit.applied)
    shifts = mode_shifts(rm, fit.alpha, amplitude, sigma)
    if floor is not None:
        shifts.floor = float(floor)
    return shifts


def unclaimed(within: bool, n_added: int, after_structured: bool, finished: bool = True) -> bool:
    """Whether a closure claims nothing: its baseline's misfit is within the model's own error (``within``,
    :attr:`ModeShifts.within`) and the effects it added, if any, did not take the residual to the noise (they fitted
    part of that error: the fifth held-out set's clean he08 got a 2 % sensor gain so). Effects that do take it to
    the noise stand (the three-plate closure table's, from 0.6-3.1 % rms of misfit against 3.0-3.5 % for one mode
    off: on the model's own mesh a 0.15 kg mass leaves little once alpha is refitted, and is found). A selection the
    time limit stopped (``finished`` False) did not look far enough to say so."""
    return bool(within) and finished and (n_added == 0 or after_structured)
