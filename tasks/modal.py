"""Modal data's steps, one core call each: read and match the measured modes to a model, correlate (FE
modes at the test DOFs, MAC, pairing, frequency differences, COMAC), the MAC picture, the modal update
(:mod:`fe_core.modal_update`; its fit under the driver, :mod:`tasks.modal_fit`) with its FE runs logged to
the run folder, and the identifiability check.
The commands are :mod:`flows.correlate` and :mod:`flows.modal_update`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fe_core.correlation import comac, frequency_differences, mac_matrix, pair_modes, pairing_report
from fe_core.modal_update import ModalResidual, identifiability
from tasks.io.measured.frf import MeasuredDataError
from tasks.io.measured.modes import read_modes
from tasks.modal_data import band_limit, check_band, match_modes
from tasks.runstore import atomic_write_json

__all__ = ["load_modal_data", "correlate", "mac_figure", "modal_residual", "check_identifiable",
           "write_runs", "N_EXTRA_MODES"]

#: Model modes computed beyond the measured ones, for pairing and tracking.
N_EXTRA_MODES = 6


def load_modal_data(measured_path, model, upper: float, modes=None, check: bool = True):
    """Read (unless ``modes`` are given), match and band-check (unless not ``check``: an eigen-solve) a modal
    file: :class:`tasks.modal_data.ModalData` and ``n_model``."""
    modes = read_modes(measured_path) if modes is None else modes
    data = match_modes(modes, model)
    n_model = min(modes.n_modes + N_EXTRA_MODES, model.n_dofs - 1)
    if check:
        check_band(modes, band_limit(model, n_model, upper), n_model)
    return data, n_model


def correlate(data, model, theta, n_model: int, threshold: float) -> dict:
    """FE modes at ``theta`` read at the test DOFs against the measured ones: a JSON-ready dict."""
    alpha, gamma = model.factors(theta)
    from fe_core.solvers.modal import eigenmodes

    freqs, vecs = eigenmodes(model.stiffness(alpha), model.mass(gamma), n_model)
    psi = (data.outputs.T @ vecs).T
    m = data.modes
    mac = mac_matrix(m.shapes, psi)
    model_names = [f"model mode {k + 1}" for k in range(n_model)]
    pairing = pair_modes(mac, threshold, m.names, model_names)
    diffs = frequency_differences(m.frequencies_hz, freqs, pairing)
    co = comac(m.shapes[pairing.test], psi[pairing.model]) if pairing.n_pairs else np.ones(len(m.dofs))
    return {
        "theta": np.asarray(theta, float).tolist(), "threshold": threshold,
        "test_modes": m.names, "test_frequencies_hz": m.frequencies_hz.tolist(),
        "model_frequencies_hz": freqs.tolist(), "mac": mac.tolist(),
        "pairs": [{"test": m.names[t], "model": model_names[j], "f_test_hz": float(m.frequencies_hz[t]),
                   "f_model_hz": float(freqs[j]), "difference": float(d), "mac": float(v)}
                  for t, j, d, v in zip(pairing.test, pairing.model, diffs, pairing.mac)],
        "unpaired_test": [m.names[k] for k in pairing.unpaired_test], "messages": pairing.messages,
        "comac": dict(zip(m.dofs, co.tolist())),
        "table": pairing_report(pairing, m.frequencies_hz, freqs, m.names, model_names),
    }


def mac_figure(result: dict, path: Path, title: str) -> Path:
    """The MAC matrix as a picture (PNG), test modes down, model modes across, pairs outlined."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    mac = np.asarray(result["mac"])
    fig = Figure(figsize=(1.2 + 0.55 * mac.shape[1], 1.2 + 0.55 * mac.shape[0]))
    ax = fig.add_subplot()
    im = ax.imshow(mac, vmin=0, vmax=1, cmap="viridis")
    for i in range(mac.shape[0]):
        for j in range(mac.shape[1]):
            ax.text(j, i, f"{mac[i, j]:.2f}", ha="center", va="center", fontsize=7,
                    color="black" if mac[i, j] > 0.5 else "white")
    names = [n for n in result["test_modes"]]
    ax.set_yticks(range(len(names)), names)
    ax.set_xticks(range(mac.shape[1]), [str(k + 1) for k in range(mac.shape[1])])
    ax.set_xlabel("model mode")
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, label="MAC")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def modal_residual(data, model, n_model, sigma_f, sigma_s, threshold) -> ModalResidual:
    m = data.modes
    return ModalResidual(model, data.outputs, m.frequencies_hz, m.shapes, sigma_f, sigma_s, n_model, threshold,
                         m.names)


def check_identifiable(residual: ModalResidual, names: list[str], source: str) -> list[str]:
    """Refuse fewer paired modes than parameters when the data cannot make up for them.

    With frequencies only, fewer paired modes than parameters is refused, naming the parameters the
    frequencies cannot fix (:func:`fe_core.modal_update.identifiability`). With shapes, the shapes carry
    information too: fewer modes are accepted when the whole Jacobian (frequencies and shapes) at the nominal
    model has full numerical rank, else refused naming the parameters past its rank. Returns notes.
    """
    theta0 = np.zeros(len(names))
    pairing = residual.set_active(theta0)
    if pairing.n_pairs >= len(names):
        return []
    lost = identifiability(residual.evaluate(theta0)["J"], names)
    shapes = residual.sigma_u is not None
    if shapes and not lost:
        return [f"{pairing.n_pairs} paired modes for {len(names)} parameters: the shapes make up for the "
                "missing frequencies (the Jacobian of frequencies and shapes has full rank at the nominal model)"]
    what = "the frequencies and shapes" if shapes else "the frequencies"
    raise MeasuredDataError(
        f"{source}: {pairing.n_pairs} paired mode(s) for {len(names)} parameters: fewer paired modes than "
        f"parameters, and {what} cannot determine {', '.join(lost)} (not identifiable)"
        + ("; unpaired: " + "; ".join(pairing.messages) if pairing.messages else ""))


def write_runs(residual: ModalResidual, folder: Path) -> None:
    """Every FE run of ``residual`` so far (parameters, frequencies, and the stage that asked for it) to
    ``<folder>/modal_runs.jsonl``; the runs logged there before by stages this process did not run (a resumed
    run reads them back) are kept, first."""
    from tasks.runstore import atomic_write_bytes

    path = Path(folder) / "modal_runs.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    ours = {h.get("stage") for h in residual.history}
    kept = []
    if path.exists():
        kept = [h for h in (json.loads(line) for line in path.read_text().splitlines() if line.strip())
                if h.get("stage") not in ours]
    runs = [dict(h, run=i + 1) for i, h in enumerate(kept + list(residual.history))]
    text = "".join(json.dumps(h) + "\n" for h in runs)
    atomic_write_bytes(path, text.encode())


def write_json(path: Path, obj) -> None:
    atomic_write_json(Path(path), obj)


def shapes_figure(data, model, theta, result: dict, path: Path) -> Path | None:
    """Paired shapes on the mesh: per pair, the model mode's displacement along the test direction on the
    mesh's nodes (small dots) and the measured values at the test points (large circles, the same colour
    scale, after the modal scale factor brings the model shape onto the measured one). None without a mesh."""
    if model.mesh is None or not result["pairs"]:
        return None
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    alpha, gamma = model.factors(theta)
    n_model = len(result["model_frequencies_hz"])
    _, shapes, _ = model.modes(alpha, n_model, gamma)  # (n_model, n_nodes, 3)
    L = data.outputs.tocsc()
    # where each test DOF is drawn: its largest entry (the one DOF of a sensor at a node along x, y or z; a
    # point read through an element's shape functions, point_placement = "interpolate", has several)
    big = np.array([L.indptr[k] + int(np.argmax(np.abs(L.data[L.indptr[k]:L.indptr[k + 1]])))
                    for k in range(L.shape[1])], dtype=int)
    rows, sign = L.indices[big], np.sign(L.data[big])
    dofs = model.free_dofs[rows]
    nodes, comp = dofs // 3, dofs % 3
    xyz = model.mesh.nodes
    top = np.isclose(xyz[:, 2], xyz[:, 2].max())
    m = data.modes
    pairs = result["pairs"]
    fig = Figure(figsize=(9, 1.0 + 1.6 * len(pairs)))
    for k, pair in enumerate(pairs):
        t = m.names.index(pair["test"])
        j = int(pair["model"].split()[-1]) - 1
        field = shapes[j][:, comp[0]]
        at_test = L.T @ shapes[j].reshape(-1)[model.free_dofs]   # the model's reading of each test DOF
        msf = (m.shapes[t] @ at_test) / (at_test @ at_test)
        ax = fig.add_subplot(len(pairs), 1, k + 1)
        scale = np.abs(m.shapes[t]).max()
        sc = ax.scatter(xyz[top, 0], xyz[top, 1], c=msf * field[top], s=4, cmap="coolwarm", vmin=-scale, vmax=scale)
        ax.scatter(xyz[nodes, 0], xyz[nodes, 1], c=m.shapes[t] * sign, s=60, cmap="coolwarm",
                   vmin=-scale, vmax=scale, edgecolors="black")
        ax.set_aspect("equal")
        ax.set_title(f"{pair['test']} {pair['f_test_hz']:.1f} Hz  <->  {pair['model']} {pair['f_model_hz']:.1f} Hz, "
                     f"MAC {pair['mac']:.3f}", fontsize=8)
        ax.tick_params(labelsize=6)
        fig.colorbar(sc, ax=ax, fraction=0.02)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    return path
