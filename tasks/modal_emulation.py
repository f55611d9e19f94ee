"""The adaptive loop's emulation by default (config ``emulate = "modes"``, ``loop = "paper"``).

What changes against the paper's steps (Table 2), each stage keeping its name and files:

* ``samples`` of iteration 1: the nominal model (every factor 0) is one of the q uniform samples;
* ``fe``: each FE run also gives the lowest modes of its parameters (columns ``omega2_<r>``,
  ``participation_<r>``; :func:`n_modes` says how many, iteration 1's FE stage records it for the run);
* ``train``: the MRGP (one length scale per parameter, no Table 1 ``l~`` bound) emulates the modes and the
  remainder of the receptance at the kept values (:class:`mrgp_core.modal_outputs.ModalLayout`) from all
  FE runs so far, instead of the relative residuals (with many outputs: the modes in an MRGP of their own,
  :func:`separate_modes`);
* ``predict``: the candidates of the paper's distribution, plus the end points of Gauss-Newton runs on the
  emulator's mean from the ``GN_STARTS`` best FE samples and the ``GN_STARTS`` best candidates; a
  candidate's error is Eq. (6b) of the receptance its emulated modes give (a composite objective);
* ``errors``, ``distribution`` and ``select``: unchanged.

Why: docs/update-results.md (the paper's loop on the benchmark). ``emulate = "errors"`` keeps the paper's
emulation of the residuals.
"""

from __future__ import annotations

import numpy as np

from mrgp_core import adaptive
from mrgp_core.modal_outputs import BAND_FACTOR, ModalLayout, modes_to_emulate

__all__ = ["GN_STARTS", "n_modes", "layout", "training_set", "separate_modes", "Emulator", "predict"]

#: Gauss-Newton runs on the emulator's mean per predict stage: from this many best FE samples and as many
#: best candidates.
GN_STARTS = 5

def n_modes(config, freqs_hz) -> int:
    """Modes the FE runs give for the emulator: the nominal model's below ``BAND_FACTOR`` times the highest
    measured frequency, plus one (:func:`mrgp_core.modal_outputs.modes_to_emulate`). Computed by iteration 1's
    FE stage, which records it for the run."""
    from tasks import stages

    highest = float(np.max(freqs_hz))
    model = stages.load_model(config.model)
    alpha, gamma = model.factors(np.zeros(model.n_parameters))
    available = model.n_dofs - 1
    k = min(8, available)
    while True:  # past the band, so the gap after the last mode taken shows (a close pair is taken whole)
        freqs = model.natural_frequencies(alpha, k, gamma)
        if freqs[-1] >= 2 * BAND_FACTOR * highest or k == available:
            return modes_to_emulate(freqs, highest, available)
        k = min(2 * k, available)


#: Bytes of working memory per block of candidates scored on the emulator (the receptance of each candidate
#: at every kept value, mode by mode, is built at once).
BLOCK_BYTES = 2e8


def separate_modes(config, layout: ModalLayout) -> bool:
    """Whether the modes get an MRGP of their own: when the config's ``outputs`` puts all the outputs in a
    reduced basis, a basis of the standardised outputs would spend itself on the far more numerous remainder
    values and lose the modes (measured on the hammer data: 28 modal of 18,162 outputs, frequencies off by
    36-187 Hz after projection). The modes then have a full MRGP (reduced only above
    :data:`tasks.stages.AUTO_REDUCED_ABOVE` of them), which the train stage fits; the remainder a reduced one at
    the same hyper-parameters."""
    from tasks import stages

    return stages.reduced_outputs(config.outputs, layout.n_outputs)


class Emulator:
    """The emulated outputs' mean at candidates, from stored hyper-parameters (see :func:`separate_modes`)."""

    def __init__(self, config, X: np.ndarray, Y: np.ndarray, layout: ModalLayout, hyper):
        import mrgp_core
        from tasks import stages

        X, Y = stages.merge_duplicates(X, Y)
        n = layout.n_modal
        if separate_modes(config, layout):
            modes = mrgp_core.condition_reduced if stages.reduced_outputs("auto", n) else mrgp_core.condition
            self.parts = [modes(X, Y[:, :n], hyper), mrgp_core.condition_reduced(X, Y[:, n:], hyper)]
        else:
            self.parts = [mrgp_core.condition(X, Y, hyper)]

    def mean(self, points: np.ndarray) -> np.ndarray:
        points = np.atleast_2d(points)
        return np.hstack([part.predict(points, return_var=False)[0] for part in self.parts])


def layout(config, data, modes: int) -> ModalLayout:
    """The emulated outputs' layout for the run's kept values (``data.cells``, frequency-major)."""
    from tasks import stages

    line, channel = data.cells
    omega = 2.0 * np.pi * np.asarray(data.frequencies_hz, float)[line]
    damping = tuple(float(v) for v in stages.load_model(config.model).damping)
    return ModalLayout(omega, np.asarray(channel, int), int(data.amplitude.shape[1]), damping, modes)


def training_set(store, config, iteration: int, data) -> tuple[np.ndarray, np.ndarray, np.ndarray, ModalLayout]:
    """(X (r, m), Y (r, n_outputs), overall errors (r,), layout): every successful FE run of iterations
    1..``iteration``, in the order of :func:`tasks.stages.training_data`, and its emulated outputs."""
    from tasks import stages

    ids, X, _, E = stages.training_data(store, iteration)
    p, n = data.amplitude.shape
    line, channel = data.cells
    by_id = stages.fe_results(store, iteration)
    counts = {sum(c.startswith("omega2_") for c in by_id[int(sid)].columns) for sid in ids}
    if len(counts) != 1 or 0 in counts:
        raise RuntimeError(f"{store.root}: the FE results hold {sorted(counts)} modes; the modal emulator needs the "
                           "same modes in every FE run (was the run started with emulate = \"errors\"?)")
    modes = counts.pop()
    lay = layout(config, data, modes)
    Y = np.empty((len(ids), lay.n_outputs))
    for i, sid in enumerate(ids):
        part = by_id[int(sid)]
        Z = (part["real"].to_numpy() + 1j * part["imag"].to_numpy()).reshape(p, n)[line, channel]
        omega2 = np.array([part[f"omega2_{r + 1}"].iloc[0] for r in range(modes)])
        P = np.array([part[f"participation_{r + 1}"].to_numpy()[:n] for r in range(modes)])
        Y[i] = lay.outputs(omega2, P, Z)
    return X, Y, E, lay


def predict(store, config, iteration: int, data, hyper: dict, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(candidates, predicted overall errors): ``C`` (w, m) and the Gauss-Newton end points on the
    emulator's mean appended; errors of the receptance the emulated modes give (Eq. 6b)."""
    import mrgp_core
    from tasks import stages
    from tasks.hybrid import fitted

    X, Y, E, lay = training_set(store, config, iteration, data)
    best = X[np.argsort(E, kind="stable")[:GN_STARTS]]
    h = mrgp_core.Hyperparameters(length_scale=stages._length_scales(hyper), nugget=float(hyper["nugget"]))
    emulator = Emulator(config, X, Y, lay, h)
    residual, _ = fitted(data)
    block = max(1, int(BLOCK_BYTES // (40 * len(lay.omega) * lay.n_modes + 16 * lay.n_outputs)))

    def residuals(points):
        r = residual(lay.receptance(emulator.mean(points)))
        return np.where(np.isfinite(r), r, 1e3)

    def errors(points):
        points = np.atleast_2d(points)
        return np.concatenate([np.mean(np.abs(residuals(points[i:i + block])), axis=1)
                               for i in range(0, len(points), block)])

    predicted = errors(C)
    starts = np.vstack([best, C[np.argsort(predicted, kind="stable")[:GN_STARTS]]])
    low, high = stages.solver_box(config, C.shape[1])
    refined = adaptive.refine_on_emulator(lambda x: residuals(x[None])[0], starts, low, high, tolerance=1e-14)
    return np.vstack([C, refined]), np.concatenate([predicted, errors(refined)])
