"""The adaptive loop's trust-region variant (config ``loop = "trust-region"``; ``loop = "paper"``, the default, keeps Table 2's steps).

What changes against the paper's steps (Table 2), each stage keeping its name and files:

* ``samples`` of iteration 1: the nominal model (every factor 0) is one of the q uniform samples;
* ``distribution``: a trust region around the best FE sample (:class:`mrgp_core.adaptive.TrustRegion`,
  its side, counters and best error in the stage record) instead of the normal distribution of the best z;
* ``train``: the MRGP (one length scale per parameter) emulates the model's inverse receptance ``1 / Z``
  at the measured values, from the FE runs inside twice the region (at least q);
* ``predict``: w candidates uniform in the region and the end points of Gauss-Newton runs on the emulator's
  mean from the ``GN_STARTS`` best of them; each candidate's error is computed from its emulated response
  (the run's amplitude or complex residual, Eq. 6b);
* ``select``: unchanged (the s best predicted, a minimum distance apart).

The pure pieces are in :mod:`mrgp_core.adaptive`; this module reads the run folder for them.
"""

from __future__ import annotations

import numpy as np

from mrgp_core import adaptive

__all__ = ["GN_STARTS", "region", "responses", "training_set", "predict"]

#: Gauss-Newton runs on the emulator's mean per predict stage (from the best candidates).
GN_STARTS = 20


def region(store, iteration: int) -> adaptive.TrustRegion:
    """The trust region recorded by iteration ``iteration``'s distribution stage."""
    info = store.stage_info(iteration, "distribution")
    tr = info["trust_region"]
    return adaptive.TrustRegion(np.asarray(tr["centre"], float), float(tr["length"]), int(tr["successes"]),
                                int(tr["failures"]), float(tr["best"]))


def responses(store, iteration: int, data) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sample ids, X (r, m), Z (r, k) complex at the kept values) of every successful FE run of iterations
    1..``iteration``, in the order of :func:`tasks.stages.training_data`."""
    from tasks import stages
    from tasks.hybrid import _grid

    ids, X, _, _ = stages.training_data(store, iteration)
    p, n = data.amplitude.shape
    line, channel = data.cells
    m = X.shape[1]
    Z = []
    by_id = stages.fe_results(store, iteration)
    for sid in ids:
        grid, _ = _grid(by_id[int(sid)], p, n, m)
        Z.append(grid[line, channel])
    return ids, X, np.array(Z)


def training_set(store, config, iteration: int, data) -> tuple[np.ndarray, np.ndarray]:
    """(X, G): the FE runs inside twice the trust region (at least q) and their inverse receptance (r, 2 k)."""
    from tasks import stages

    _, X, Z = responses(store, iteration, data)
    tr = region(store, iteration)
    lower, upper = stages.parameter_box(config, X.shape[1])
    keep = adaptive.local_training_set(X, tr, lower, upper, config.q)
    return X[keep], adaptive.inverse_receptance(Z[keep])


def predict(store, config, iteration: int, data, hyper: dict, rng: np.random.Generator) -> tuple[np.ndarray,
                                                                                                   np.ndarray]:
    """(candidates (w + GN_STARTS, m), predicted overall errors): uniform in the region, then Gauss-Newton
    end points on the emulator's mean."""
    import mrgp_core
    from tasks import stages
    from tasks.hybrid import fitted

    X, G = training_set(store, config, iteration, data)
    X, G = stages.merge_duplicates(X, G)
    h = mrgp_core.Hyperparameters(length_scale=stages._length_scales(hyper), nugget=float(hyper["nugget"]))
    emulator = mrgp_core.condition(X, G, h)
    residual, _ = fitted(data)
    tr = region(store, iteration)
    lower, upper = stages.parameter_box(config, X.shape[1])
    low, high = tr.box(lower, upper)
    C = low + (high - low) * rng.random((config.w, X.shape[1]))
    C = C[np.all(C > -1.0, axis=1)]  # the domain's open edge (the box may start at -1)

    def errors(points):
        mean, _ = emulator.predict(np.atleast_2d(points), return_var=False)
        r = residual(adaptive.receptance_from_inverse(mean))
        return np.mean(np.abs(np.where(np.isfinite(r), r, 1e3)), axis=1)

    def residuals_of(x):
        mean, _ = emulator.predict(x[None], return_var=False)
        r = residual(adaptive.receptance_from_inverse(mean))[0]
        return np.where(np.isfinite(r), r, 1e3)

    predicted = errors(C)
    starts = C[np.argsort(predicted, kind="stable")[:GN_STARTS]]
    refined = adaptive.refine_on_emulator(residuals_of, starts, low, high)
    refined = refined[np.all(refined > -1.0, axis=1)]
    return np.vstack([C, refined]), np.concatenate([predicted, errors(refined)])
