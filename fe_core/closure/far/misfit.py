"""What the model's own error would give: an effect's gain judged against a misfit that is correlated along
frequency, not against white noise alone.

The closure's decision (:func:`fe_core.closure.decisions.decide`) adds an effect when its extended BIC,
``N ln(RSS / N) + k ln N + 2 ln L``, beats the model without it. That score treats the ``N`` residual values as
independent. They are when what is left is measurement noise. They are not when what is left is the model's own
error (a coarse mesh a little too stiff in some modes, a parametrisation too coarse for the stiffness's real
distribution): that misfit is smooth along frequency within each resonance, a value and its neighbours say the
same, and a negligible mass or a spring to the ground at some node, chosen from thousands, takes out a per cent of
it; with ``N`` = 6,000 values that per cent is worth 60 units of ``N ln RSS`` against a penalty of about 26, and it
is added (issue 40's box arm: a 0.75 g mass and a 5.8e5 N/m spring to the ground after the true 0.6 kg mass).

The same score with the number of **effectively independent values** ``N_eff`` in place of ``N``
(:func:`effective_values`, the variance inflation of a correlated sequence: Bayley & Hammersley 1946; the
effective sample size of time-series analysis) judges the gain against the misfit as it is:

    dEBIC_eff = N_eff ln(RSS_1 / RSS_0) + k ln N_eff + 2 ln L,

with ``N_eff`` from the residual *with* the candidate (the one a right effect leaves: noise and the model's own
error). For white noise ``N_eff`` is ``N`` and this is the extended BIC as before; for a misfit correlated over
``l`` lines it is about ``N / l``: a gain must then be ``l`` times larger to count. A sizeable true effect still
counts (it takes out most of the sum of squares: ``ln(RSS_1 / RSS_0)`` of -2 to -5 against a penalty of 20-30).

:func:`smooth_misfit` reports the size of the misfit left beyond the noise (the rms of ``ln|Z|`` in excess of the
noise level), the number the verdict quotes with an explained effect.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["effective_values", "effective_ebic", "smooth_misfit", "judge_misfit", "mark_polish", "worth_checking", "Misfit", "MAX_LAG",
           "MISFIT_SHARE", "POLISH"]

#: Largest lag (lines) of the autocorrelation sum: about ten half-power bandwidths of 1 Hz lines at 1 % damping
#: round 100-500 Hz would be more; the sum stops earlier at the first lag whose correlation is not positive.
MAX_LAG = 30


def _weighted(residual: np.ndarray, sigma) -> np.ndarray:
    r = np.asarray(residual, float)
    if sigma is None:
        return r
    s = np.broadcast_to(np.asarray(sigma, float), r.shape)
    return r / s


def effective_values(residual: np.ndarray, sigma=None, max_lag: int = MAX_LAG) -> float:
    """Effectively independent values of a residual (p, n_s): ``N / (1 + 2 sum_k rho_k)``, the autocorrelation
    ``rho_k`` along frequency pooled over the channels (each channel's mean removed), summed from lag 1 up to
    ``max_lag`` or to the first lag that is not positive (the initial positive sequence), at least 1 value per
    channel. ``sigma`` (a level or per-value levels, broadcast to the residual) weights the residual first: with a
    noise floor the antiresonances' values are noisier, not correlated.

    Lines are taken as they come (a residual on several windows joins them; a few pairs across a window's edge are
    a small share of the sum)."""
    r = _weighted(residual, sigma)
    if r.ndim == 1:
        r = r[:, None]
    p, n = r.shape
    x = r - r.mean(axis=0, keepdims=True)
    var = float(np.sum(x * x))
    if var <= 0 or p < 3:
        return float(r.size)
    total = 0.0
    for k in range(1, min(max_lag, p - 1) + 1):
        rho = float(np.sum(x[k:] * x[:-k])) / var
        if rho <= 0:
            break
        total += rho
    return float(np.clip(r.size / (1.0 + 2.0 * total), n, r.size))


def effective_ebic(rss_with: float, rss_without: float, n_eff: float, n_parameters: int, n_locations: int) -> float:
    """``N_eff ln(RSS_1 / RSS_0) + k ln N_eff + 2 ln L``: negative when the effect's gain stands out from the misfit
    (the module docstring)."""
    n_eff = max(float(n_eff), 2.0)
    ratio = max(float(rss_with), 1e-300) / max(float(rss_without), 1e-300)
    return float(n_eff * np.log(ratio) + n_parameters * np.log(n_eff) + 2.0 * np.log(max(n_locations, 1)))


def smooth_misfit(residual: np.ndarray, sigma) -> float:
    """The rms of the residual in excess of the noise, ``sqrt(max(0, mean(r^2) - mean(sigma^2)))`` (in ``ln|Z|``,
    about a relative amplitude error): the model's own misfit left once the noise is accounted for."""
    r = np.asarray(residual, float)
    s2 = float(np.mean(np.broadcast_to(np.asarray(sigma, float), r.shape) ** 2))
    return float(np.sqrt(max(0.0, float(np.mean(r * r)) - s2)))


#: The structure left after the effects is taken for the model's own misfit when no further candidate stands out
#: and its size (:func:`smooth_misfit`) is at most this share of what the alpha-only fit left (the effects took
#: out at least 1 - 0.25^2 = 94 % of the sum of squares beyond the noise). Set on the development cases
#: (docs/results/closure-far-effects.md): the box arm's coarse-mesh error after its true mass, and the plate with a mass
#: layer (outside the library) after the point masses that stand in for it.
MISFIT_SHARE = 0.25


@dataclass
class Misfit:
    """What is left beyond the noise, and whether it is the model's own: ``before`` and ``after`` the effects (rms
    of ``ln|Z|`` beyond the noise, :func:`smooth_misfit`), their ratio ``share``, ``own`` (the closure may say
    ``explained`` with it) and why."""

    before: float
    after: float
    share: float
    own: bool
    reason: str

    def to_dict(self) -> dict:
        return {"smooth_misfit_before": self.before, "smooth_misfit": self.after, "misfit_share": self.share,
                "misfit_is_model_error": self.own, "misfit_reason": self.reason}


def judge_misfit(before: np.ndarray, after: np.ndarray, sigma, nothing_stands_out: bool,
                 share: float = MISFIT_SHARE, bar: float | None = None) -> Misfit:
    """Is the structure left after the effects the model's own misfit (mesh, parametrisation)? Yes when nothing
    more stands out from it (``nothing_stands_out``: the forward selection stopped because no checked candidate's
    gain stood out, :func:`effective_ebic`) and it is small beside what the effects explained: its size beyond the
    noise ``sigma`` (a level or per-value levels) at most ``share`` of the alpha-only fit's (``before``), and at
    most ``bar`` when the model's own error was measured against its refined mesh
    (:attr:`fe_core.closure.far.shifts.ModeShifts.bar`): a large effect outside the library (a mass layer) stood in
    for by point masses leaves a quarter of its misfit, several times what the mesh leaves (held-out hi04)."""
    b, a = smooth_misfit(before, sigma), smooth_misfit(after, sigma)
    ratio = a / b if b > 0 else 0.0
    above_bar = bar is not None and a > bar
    own = bool(nothing_stands_out and ratio <= share and not above_bar)
    if own:
        why = (f"a misfit of {a:.2%} rms beyond the noise is left, {ratio:.0%} of the {b:.2%} before the effects, and "
               "no further effect stands out from it: the model's own error (mesh, parametrisation)")
    elif not nothing_stands_out:
        why = "the forward selection stopped at its most effects, or at noise"
    elif above_bar and ratio <= share:
        why = (f"a misfit of {a:.2%} rms beyond the noise is left, {ratio:.0%} of the {b:.2%} before the effects but "
               f"more than the model's own error measured on its refined mesh ({bar:.2%})")
    else:
        why = (f"a misfit of {a:.2%} rms beyond the noise is left, {ratio:.0%} of the {b:.2%} before the effects "
               f"(more than {share:.0%}): more than the model's own error")
    return Misfit(b, a, ratio, own, why)


#: Once the misfit left is the model's own level (at most :data:`MISFIT_SHARE` of the alpha-only fit's), a further
#: effect must take out at least this share of its sum of squares beyond the noise: a missing effect takes out most
#: of the misfit it leaves, a polish of the model's own error a part. Set on the development cases
#: (docs/results/closure-far-effects.md): the tet10 plate after its true mass, a damaged patch took 10 % of the misfit
#: left (7 % of the sum of squares).
POLISH = 0.5


def mark_polish(baseline: np.ndarray, current: np.ndarray, checked, sigma, share: float = MISFIT_SHARE,
                polish: float = POLISH) -> bool:
    """Mark as ``negligible`` the checked candidates (each with its fit) that only polish the model's own misfit:
    when the misfit of ``current`` (the residual with the effects so far) is at most ``share`` of ``baseline``'s
    (the alpha-only fit's), a candidate must lower its square beyond the noise ``sigma`` (:func:`smooth_misfit`) by
    at least ``polish``. Returns whether the rule applied (the current misfit is at the model's own level)."""
    b, a = smooth_misfit(baseline, sigma), smooth_misfit(current, sigma)
    if b <= 0 or a > share * b:
        return False
    for c in checked:
        if c.fit is None:
            continue
        left = smooth_misfit(c.fit.residual, sigma)
        if left**2 > (1.0 - polish) * a**2:
            c.negligible = True
    return True


def worth_checking(baseline: np.ndarray, current: np.ndarray, predicted_rss, sigma, share: float = MISFIT_SHARE,
                   polish: float = POLISH) -> bool:
    """Whether any candidate could pass :func:`mark_polish`: always above the model's own level; at it, when some
    candidate's predicted sum of squares (the linearised screen's, alpha refitted) lowers the misfit's square by at
    least half of ``polish`` (the screen near the fit is close to the full fit; the half is its margin). Saves the
    full checks of a round that can only polish (minutes on a 30k-DOF model)."""
    b, a = smooth_misfit(baseline, sigma), smooth_misfit(current, sigma)
    if b <= 0 or a > share * b or a <= 0:
        return True
    r = np.asarray(current, float)
    s2 = float(np.mean(np.broadcast_to(np.asarray(sigma, float), r.shape) ** 2))
    left = [max(0.0, float(x) / r.size - s2) for x in predicted_rss]
    return bool(left) and min(left) <= (1.0 - 0.5 * polish) * a**2
