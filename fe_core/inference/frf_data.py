"""The measured FRFs an update fits, and their residual: one object from the file to the closure.

:class:`FRFData` holds the measured values at the selected lines and the model's channels, which of them are
kept (``mask``), and computes every residual the tool uses from the model's receptance:

* the relative residual of Eq. 5, ``|Z| / u - 1`` at the kept values, frequency-major, channels fastest; or,
  with ``residual = "complex"``, the real and imaginary parts of ``(Z - H) / |H|`` (real parts first, k doubles).
  The strategies fit it; its mean absolute value is the overall error of Eq. 6b, per channel Eq. 15;
* the log amplitude residual ``ln(|Z| / u)`` (multiplicative noise is additive there), which the noise tests,
  the intervals and the closure use, on the kept values or on the lines where every channel is kept
  (:attr:`complete_lines`: the screens and fits of the closure need a full (lines, channels) grid).

Model values come either as the full grid ``Z`` (..., p, n) of an FE run (:meth:`kept` picks the kept values)
or as the vector ``z`` (..., k) at the kept values (what the strategies carry). Calling the object on ``z``
gives the relative residual, so it is the residual the strategies take (:mod:`strategies.gauss_newton`).

The tool's matched data (``tasks.update_data.UpdateData``: channels resolved against the model, the line
selection, where each value came from in the file) extends this class; the cores see only this part.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .residual import overall_error

__all__ = ["FRFData", "RESIDUAL_KINDS"]

#: The relative residual's kinds: the paper's amplitude residual (Eq. 5), or real and imaginary parts.
RESIDUAL_KINDS = ("amplitude", "complex")


@dataclass(frozen=True, eq=False)
class FRFData:
    """Measured FRFs at the selected lines, the values kept, and the residuals of model FRFs against them.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (p,), Hz
        The selected lines.
    amplitude : ndarray, shape (p, n), m/N
        Receptance amplitude ``u`` at them (``n`` channels), positive where kept.
    complex_frf : ndarray, shape (p, n), complex, or None
        Receptance, sign-corrected to the model's directions, when the data carry phase.
    mask : ndarray of bool, shape (p, n)
        The values that enter the residual (e.g. coherence high enough).
    residual : {"amplitude", "complex"}
        Which relative residual the strategies fit.
    native_power : ndarray of int, shape (n,), or None
        Each channel as measured: receptance ``(j w)^0``, mobility 1, accelerance 2 (None: receptance). The
        noise of a sensor has its floor in these units (:meth:`native_amplitude`).
    noise : NoiseModel or None
        The noise per line and channel as the measurement states it (coherence and averages, raw records:
        :class:`fe_core.inference.noise.NoiseModel`); None: estimated from the residual where a test needs it
        (:meth:`noise_spec`).
    """

    frequencies_hz: np.ndarray
    amplitude: np.ndarray
    complex_frf: np.ndarray | None
    mask: np.ndarray
    residual: str = "amplitude"
    native_power: np.ndarray | None = None
    noise: object = None

    @classmethod
    def grid(cls, frequencies_hz, amplitude, complex_frf=None, residual: str | None = None) -> "FRFData":
        """Every value of a full (p, n) grid kept; complex residuals when ``complex_frf`` is given (unless
        ``residual`` says otherwise). A 1-D ``amplitude`` (p,) is one channel."""
        u = np.asarray(amplitude, float)
        u = u[:, None] if u.ndim == 1 else u
        H = None if complex_frf is None else np.asarray(complex_frf, complex).reshape(u.shape)
        kind = residual or ("complex" if H is not None else "amplitude")
        return cls(np.asarray(frequencies_hz, float), u, H, np.ones(u.shape, dtype=bool), kind)

    def __post_init__(self) -> None:
        if self.residual not in RESIDUAL_KINDS:
            raise ValueError(f"residual must be one of {', '.join(RESIDUAL_KINDS)}, got {self.residual!r}")
        if self.residual == "complex" and self.complex_frf is None:
            raise ValueError("residual = 'complex' needs the measured phase (complex_frf)")

    # -- where the kept values sit -----------------------------------------------------------------------
    @property
    def n_channels(self) -> int:
        return int(self.amplitude.shape[1])

    @cached_property
    def cells(self) -> tuple[np.ndarray, np.ndarray]:
        """(line, channel) indices of the kept values, frequency-major, each shape (k,)."""
        return np.nonzero(self.mask)

    @property
    def line(self) -> np.ndarray:
        return self.cells[0]

    @property
    def channel(self) -> np.ndarray:
        return self.cells[1]

    @property
    def complex(self) -> bool:
        """The relative residual is complex (real and imaginary parts)."""
        return self.residual == "complex"

    @property
    def n_values(self) -> int:
        """Length of the relative residual vector (twice the kept values with complex residuals)."""
        return int(self.mask.sum()) * (2 if self.complex else 1)

    @cached_property
    def u(self) -> np.ndarray:
        """Measured amplitudes at the kept values, shape (k,)."""
        line, channel = self.cells
        return np.ascontiguousarray(self.amplitude[line, channel], dtype=float)

    @cached_property
    def zeta(self) -> np.ndarray | None:
        """Measured complex FRF at the kept values, shape (k,), with complex residuals; else None."""
        if not self.complex:
            return None
        line, channel = self.cells
        return np.ascontiguousarray(self.complex_frf[line, channel])

    @property
    def complete_lines(self) -> np.ndarray:
        """Selected lines where every channel is kept, bool (p,)."""
        return self.mask.all(axis=1)

    def kept(self, Z: np.ndarray) -> np.ndarray:
        """The kept values of model FRFs ``Z`` (..., p, n) -> (..., k), frequency-major (C order)."""
        line, channel = self.cells
        return np.ascontiguousarray(np.asarray(Z)[..., line, channel])

    # -- the relative residual (Eqs. 5, 6b, 15) ---------------------------------------------------------
    def __call__(self, z: np.ndarray) -> np.ndarray:
        """Relative residual of model values ``z`` (..., k) at the kept values -> (..., k), or (..., 2 k) complex."""
        if not self.complex:
            return self.amplitude_residual(z)
        r = (np.asarray(z) - self.zeta) / self.u
        return np.concatenate([r.real, r.imag], axis=-1)

    def amplitude_residual(self, z: np.ndarray) -> np.ndarray:
        """Eq. 5's ``|z| / u - 1`` at the kept values, (..., k) (also for complex data)."""
        z = np.asarray(z)
        return np.hypot(z.real, z.imag) / self.u - 1.0

    def residuals(self, Z: np.ndarray) -> np.ndarray:
        """Relative residual of model FRFs on the full grid ``Z`` (..., p, n) -> (..., k) (or (..., 2 k))."""
        return self(self.kept(Z))

    def error(self, z: np.ndarray) -> float:
        """Overall error (Eq. 6b: mean |relative residual|) of model values ``z`` (k,); inf for a failed run."""
        r = self(z)
        return overall_error(r) if np.all(np.isfinite(r)) else np.inf

    def jacobian(self, z: np.ndarray, dz: np.ndarray) -> np.ndarray:
        """``d r / d theta`` of the relative residual from ``dz`` (k, m): shape (k, m), or (2 k, m) complex."""
        if self.complex:
            d = dz / self.u[:, None]
            return np.vstack([d.real, d.imag])
        return (np.abs(z) / self.u)[:, None] * np.real(dz / z[:, None])

    def channel_errors(self, residuals: np.ndarray) -> np.ndarray:
        """Eq. (15) per channel: mean |residual| over its kept values (and both parts), (..., n)."""
        r = np.abs(np.asarray(residuals, float))
        _, channel = self.cells
        if self.complex:
            channel = np.concatenate([channel, channel])
        counts = np.bincount(channel, minlength=self.n_channels)
        sums = np.stack([np.bincount(channel, weights=row, minlength=self.n_channels)
                         for row in r.reshape(-1, r.shape[-1])])
        with np.errstate(invalid="ignore", divide="ignore"):
            out = sums / counts
        return out.reshape(r.shape[:-1] + (self.n_channels,))

    # -- the log amplitude residual ----------------------------------------------------------------------
    def log_residual(self, z: np.ndarray) -> np.ndarray:
        """``ln(|z| / u)`` at the kept values, (..., k)."""
        return np.log(np.abs(np.asarray(z)) / self.u)

    def log_grid(self, z: np.ndarray) -> np.ndarray:
        """``ln(|z| / u)`` on the (p, n) grid, NaN where a value is not kept."""
        grid = np.full(self.amplitude.shape, np.nan)
        line, channel = self.cells
        grid[line, channel] = self.log_residual(z)
        return grid

    def log_rss(self, z: np.ndarray) -> float:
        """Sum of squares of ``ln(|z| / u)`` on the lines where every channel is kept (the closure's measure)."""
        grid = self.log_grid(z)
        return float(np.sum(grid[self.complete_lines] ** 2))

    def native_amplitude(self, lines=None) -> np.ndarray:
        """The measured amplitudes in each channel's own units (receptance times ``w^native_power``), (p, n) or on
        ``lines`` (a boolean or index array over the lines)."""
        lines = slice(None) if lines is None else lines
        u = self.amplitude[lines]
        if self.native_power is None:
            return u
        w = 2.0 * np.pi * np.asarray(self.frequencies_hz, float)[lines]
        return u * w[:, None] ** np.asarray(self.native_power, float)[None, :]

    def noise_spec(self, configured: float | None = None, lines=None):
        """What the tests of a residual on ``lines`` (default: the complete lines) take as its noise (``noise=`` of
        :func:`fe_core.inference.residual.analyse_residual`): a ``configured`` relative level as it is; else the
        noise the measurement states (:attr:`noise`); else the model of a relative term and a floor per channel,
        estimated from each residual (:class:`fe_core.inference.noise.Estimated`)."""
        from .noise import Estimated

        lines = self.complete_lines if lines is None else lines
        if configured is not None:
            return float(configured)
        if self.noise is not None:
            return self.noise.lines(lines)
        return Estimated(self.native_amplitude(lines))

    def complete(self) -> tuple[np.ndarray, np.ndarray]:
        """(frequencies (p',), amplitudes (p', n)) of the lines where every channel is kept: the full grid the
        closure's screens, fits and the intervals work on."""
        lines = self.complete_lines
        return np.asarray(self.frequencies_hz, float)[lines], self.amplitude[lines]
