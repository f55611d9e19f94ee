"""Example (b): a model given as matrices exported from another FE program (scikit-fem).

    python -m benchmarks.make.matrix_example       # data/examples/cantilever_matrices/

A steel cantilever, 1.0 x 0.08 x 0.05 m, clamped at x = 0, meshed and assembled by
scikit-fem (trilinear hexahedra, ``ElementVector(ElementHex1)``, 25 x 2 x 2 cells: 5 per segment).
Four segments of 0.2 m (x < 0.8 m) are the subdomains whose stiffness is updated;
the last 0.2 m is the fixed remainder. Written per segment as Matrix Market files
(``K_seg<i>.mtx``, ``M_seg<i>.mtx``, the remainder ``K_rest.mtx``, ``M_rest.mtx``,
before constraints) with the DOF table ``dofs.csv`` (node = scikit-fem's vertex
index) and the node table ``nodes.csv`` (each vertex's coordinates, m). Five sensors read u_y at the top edge at x = 0.2 ... 1.0 m; the excitation
pushes the tip along y and z at once (weights 1 and 0.5).

``measured.csv`` is scikit-fem's own FRF (one direct complex solve per frequency with
scipy, independent of this project's Krylov solver and model reader) at the true
factors ``ALPHA_TRUE`` with 0.5 % multiplicative noise, at 0.8-1.2 times the first three
modes that the sensors see. ``measured_point_mass.csv`` is the same with a point mass that
the model file does not declare (``POINT_MASS``), for ``--close-loop`` to find;
``model_mass.toml`` updates seg3's mass factor too and ``measured_mass.csv`` has that
segment heavier (``MASS_FACTOR``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import scipy.io
import scipy.sparse as sp
import scipy.sparse.linalg as spla

OUT = Path(__file__).resolve().parents[2] / "data" / "examples" / "cantilever_matrices"
E, NU, RHO = 2.1e11, 0.3, 7850.0
DAMPING = (10.0, 1e-5)         # Rayleigh a [1/s], b [s]: damping ratios 1.2-3.9 % at the measured modes
LENGTH, WIDTH, HEIGHT = 1.0, 0.08, 0.05
SEGMENT_EDGES = (0.0, 0.2, 0.4, 0.6, 0.8)   # segments 1-4; x > 0.8 m is the remainder
SENSOR_X = (0.2, 0.4, 0.6, 0.8, 1.0)
ALPHA_TRUE = np.array([-0.15, 0.1, -0.1, 0.15])
#: The search box of every segment's alpha, in the model file (the engineer's prior: +-50 %).
BOUNDS = (-0.5, 0.5)
NOISE = 0.005
SEED = 7
#: The undeclared effect of ``measured_point_mass.csv``: a point mass (an instrument bolted on, 1.9 % of the
#: beam's 31.4 kg) on the top centre line at x = 0.68 m, inside seg4; the model file does not declare it.
POINT_MASS = {"point": (0.68, 0.04, 0.05), "mass": 0.6}
POINT_MASS_SEED = 11
#: ``model_mass.toml`` updates seg3's mass factor too; ``measured_mass.csv`` has seg3 20 % heavier than its
#: exported mass matrix (a cover plate that adds mass, not stiffness).
MASS_FACTOR = {"segment": 3, "gamma": 0.2, "bounds": (-0.3, 0.3)}
MASS_SEED = 13


def skfem_model(n_x: int = 25, n_y: int = 2, n_z: int = 2) -> dict:
    """scikit-fem's mesh, basis and matrices of the cantilever (before constraints).

    Returns a dict with ``mesh``, ``basis``, ``K`` and ``M`` (lists: segments 1-4 then
    the remainder, each (N, N), N/m and kg), ``fixed`` (DOFs at x = 0), ``sensors``
    (DOF of u_y at each sensor), ``load`` (N,), the excitation, N.
    """
    from skfem import Basis, BilinearForm, ElementHex1, ElementVector, MeshHex, asm
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    mesh = MeshHex.init_tensor(np.linspace(0, LENGTH, n_x + 1), np.linspace(0, WIDTH, n_y + 1),
                               np.linspace(0, HEIGHT, n_z + 1))
    element = ElementVector(ElementHex1())
    basis = Basis(mesh, element)
    stiffness = linear_elasticity(*lame_parameters(E, NU))

    @BilinearForm
    def mass(u, v, w):
        return RHO * dot(u, v)

    xc = mesh.p[0, mesh.t].mean(axis=0)
    groups = [np.flatnonzero((xc > a) & (xc < b)) for a, b in zip(SEGMENT_EDGES[:-1], SEGMENT_EDGES[1:])]
    groups.append(np.flatnonzero(xc > SEGMENT_EDGES[-1]))
    K, M = [], []
    for cells in groups:
        sub = Basis(mesh, element, elements=cells)
        K.append(asm(stiffness, sub).tocsr())
        M.append(asm(mass, sub).tocsr())
    p = mesh.p
    fixed = basis.nodal_dofs[:, np.flatnonzero(np.isclose(p[0], 0.0))].ravel()

    def node_at(x, y, z):
        return int(np.argmin(np.linalg.norm(p.T - [x, y, z], axis=1)))

    sensors = np.array([basis.nodal_dofs[1, node_at(x, WIDTH, HEIGHT)] for x in SENSOR_X])
    tip = node_at(LENGTH, WIDTH, HEIGHT)
    load = np.zeros(basis.N)
    load[basis.nodal_dofs[1, tip]] = 1.0
    load[basis.nodal_dofs[2, tip]] = 0.5
    return {"mesh": mesh, "basis": basis, "K": K, "M": M, "fixed": fixed, "sensors": sensors, "load": load,
            "tip": tip, "sensor_nodes": [node_at(x, WIDTH, HEIGHT) for x in SENSOR_X]}


def skfem_frf(fem: dict, alpha, freqs_hz, gamma=None) -> np.ndarray:
    """scikit-fem + scipy: receptance at the sensors, (p, 5) complex, m/N, one direct solve per frequency.

    ``gamma`` (shape (4,), optional) scales the segments' mass matrices by ``1 + gamma_i``.
    """
    from skfem import condense

    K = sum((1 + a) * Ki for a, Ki in zip(alpha, fem["K"][:-1])) + fem["K"][-1]
    M = (sum(fem["M"]) if gamma is None
         else sum((1 + g) * Mi for g, Mi in zip(np.asarray(gamma, float), fem["M"][:-1])) + fem["M"][-1])
    a, b = DAMPING
    out = []
    for f in np.asarray(freqs_hz, float):
        w = 2 * np.pi * f
        A = (K - w**2 * M + 1j * w * (a * M + b * K)).tocsc()
        Ac, Fc, xc, I = condense(A, fem["load"].astype(complex), D=fem["fixed"])
        u = np.zeros(A.shape[0], complex)
        u[I] = spla.spsolve(sp.csc_matrix(Ac), Fc)
        out.append(u[fem["sensors"]])
    return np.array(out)


def write_files(fem: dict, out: Path) -> None:
    """The matrices, DOF table and model.toml of the model (what another program would export)."""
    out.mkdir(parents=True, exist_ok=True)
    basis = fem["basis"]
    table = np.zeros((basis.N, 2), dtype=int)
    for d in range(3):
        table[basis.nodal_dofs[d], 0] = np.arange(basis.nodal_dofs.shape[1])
        table[basis.nodal_dofs[d], 1] = d
    with open(out / "dofs.csv", "w") as fh:
        fh.write("node,direction\n")
        fh.writelines(f"{n},{'xyz'[d]}\n" for n, d in table)
    write_nodes(fem, out)
    names = [f"seg{i + 1}" for i in range(len(fem["K"]) - 1)] + ["rest"]
    for name, K, M in zip(names, fem["K"], fem["M"]):
        scipy.io.mmwrite(str(out / f"K_{name}.mtx"), K, symmetry="symmetric", precision=17)
        scipy.io.mmwrite(str(out / f"M_{name}.mtx"), M, symmetry="symmetric", precision=17)
    clamped = sorted(set(int(n) for n in table[fem["fixed"], 0]))
    lines = [
        "# A steel cantilever exported by scikit-fem as matrices (python -m benchmarks.make.matrix_example).",
        'units = "SI"',
        "",
        "[matrices]",
        'dofs = "dofs.csv"',
        'nodes = "nodes.csv"        # node coordinates, m (optional: the closure locates effects with them)',
        'stiffness = "K_rest.mtx"   # the fixed remainder: x > 0.8 m',
        'mass = "M_rest.mtx"',
        "",
        "[damping]",
        f"a = {DAMPING[0]!r}",
        f"b = {DAMPING[1]!r}",
        "",
    ]
    for name in names[:-1]:
        lines += ["[[segments]]", f'name = "{name}"', f'stiffness = "K_{name}.mtx"', f'mass = "M_{name}.mtx"',
                  f"bounds = {list(BOUNDS)}", ""]
    lines += ["[[supports]]", f"nodes = {clamped}", 'fix = ["x", "y", "z"]', ""]
    for j, node in enumerate(fem["sensor_nodes"]):
        lines += ["[[sensors]]", f'name = "y at x = {SENSOR_X[j]} m"', f"node = {node}", 'direction = "y"', ""]
    lines += ["[[excitations]]", 'name = "tip y + z"', "dofs = [",
              f'  {{ node = {fem["tip"]}, direction = "y", weight = 1.0 }},',
              f'  {{ node = {fem["tip"]}, direction = "z", weight = 0.5 }},', "]", ""]
    (out / "model.toml").write_text("\n".join(lines))


def write_nodes(fem: dict, out: Path) -> None:
    """``nodes.csv``: every vertex's coordinates (node = scikit-fem's vertex index, as in ``dofs.csv``), m."""
    p = fem["mesh"].p
    with open(out / "nodes.csv", "w") as fh:
        fh.write("node,x,y,z\n")
        fh.writelines(f"{n},{float(p[0, n])!r},{float(p[1, n])!r},{float(p[2, n])!r}\n" for n in range(p.shape[1]))


def with_point_mass(fem: dict, point, mass: float) -> tuple[dict, int]:
    """scikit-fem's model with ``mass`` (kg) on u_x, u_y, u_z of the node nearest ``point`` (added to the
    remainder's mass matrix, so the segments' matrices, which the model file holds, stay as exported).
    Returns the model and the node (scikit-fem's vertex index, the DOF table's node id)."""
    p = fem["mesh"].p
    node = int(np.argmin(np.linalg.norm(p.T - np.asarray(point, float), axis=1)))
    dofs = fem["basis"].nodal_dofs[:, node]
    extra = sp.csr_matrix((np.full(3, float(mass)), (dofs, dofs)), shape=fem["M"][-1].shape)
    return {**fem, "M": fem["M"][:-1] + [fem["M"][-1] + extra]}, node


#: Measured frequencies per mode, relative to its natural frequency: the peak and both flanks out to +-20 %.
WINDOW = (0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2)


def measurement_frequencies(fem: dict, gamma=None) -> np.ndarray:
    """``WINDOW`` times each of the first three bending modes in y (the sensors' direction) at the truth, Hz:
    27 frequencies. The window decides how often the update finds the truth's basin (default settings, the
    same scikit-fem truth and noise, measured while making this example): +-4 % without the peak ended in a
    wrong basin at 24-28 % error, as did least squares from alpha = 0; 0.9-1.1 in 5 steps recovered the truth
    in 17 of 20 seeds (0-19); 0.85-1.15 in 7 steps in 6 of 8 (0-7); 0.8-1.2 in 9 steps in 20 of 20 (0-19).
    An alpha of +-0.5 moves a mode by up to -30/+22 %: the wider window keeps every peak's flank in view."""
    from skfem import condense

    K = sum((1 + a) * Ki for a, Ki in zip(ALPHA_TRUE, fem["K"][:-1])) + fem["K"][-1]
    M = (sum(fem["M"]) if gamma is None
         else sum((1 + g) * Mi for g, Mi in zip(np.asarray(gamma, float), fem["M"][:-1])) + fem["M"][-1])
    Kc, Mc, _, I = condense(K, M, D=fem["fixed"])
    vals, vecs = spla.eigsh(Kc, k=8, M=Mc, sigma=0, which="LM")
    order = np.argsort(vals)
    full = np.zeros((len(I) + len(fem["fixed"]), vecs.shape[1]))
    full[I] = vecs
    uy = np.abs(full[fem["basis"].nodal_dofs[1]]).max(axis=0)
    uz = np.abs(full[fem["basis"].nodal_dofs[2]]).max(axis=0)
    modes = [np.sqrt(vals[k]) / (2 * np.pi) for k in order if uy[k] > uz[k]][:3]
    return np.round(np.concatenate([f * np.asarray(WINDOW) for f in modes]), 1)


def main() -> int:
    from tasks.io.measured import MeasuredFRF, write_measured

    fem = skfem_model()
    write_files(fem, OUT)
    freqs = measurement_frequencies(fem)
    Z = skfem_frf(fem, ALPHA_TRUE, freqs)
    rng = np.random.default_rng(SEED)
    amp = np.abs(Z) * (1 + NOISE * rng.standard_normal(Z.shape))
    write_measured(OUT / "measured.csv", MeasuredFRF(freqs, list(range(1, Z.shape[1] + 1)), amp, None,
                                                      f"scikit-fem direct FRF at alpha {ALPHA_TRUE.tolist()}, "
                                                      f"{NOISE:.1%} noise, seed {SEED}"))
    # The same structure carrying a point mass the model file does not declare, measured at its own peaks.
    fem_pm, node = with_point_mass(fem, POINT_MASS["point"], POINT_MASS["mass"])
    freqs_pm = measurement_frequencies(fem_pm)
    Z = skfem_frf(fem_pm, ALPHA_TRUE, freqs_pm)
    rng = np.random.default_rng(POINT_MASS_SEED)
    amp = np.abs(Z) * (1 + NOISE * rng.standard_normal(Z.shape))
    write_measured(OUT / "measured_point_mass.csv", MeasuredFRF(
        freqs_pm, list(range(1, Z.shape[1] + 1)), amp, None,
        f"scikit-fem direct FRF at alpha {ALPHA_TRUE.tolist()} with an undeclared {POINT_MASS['mass']} kg point "
        f"mass at node {node}, {NOISE:.1%} noise, seed {POINT_MASS_SEED}"))
    # The model file that updates seg3's mass factor too, and a measurement with that segment heavier.
    seg = MASS_FACTOR["segment"]
    text = (OUT / "model.toml").read_text().replace(
        f'name = "seg{seg}"\n', f'name = "seg{seg}"\nupdate = ["stiffness", "mass"]   # and gamma_{seg}, its mass '
        f'factor\nmass_bounds = {list(MASS_FACTOR["bounds"])}\n')
    (OUT / "model_mass.toml").write_text(text.replace(
        "# A steel cantilever exported",
        f"# The cantilever with seg{seg}'s mass factor updated too. A steel cantilever exported"))
    gamma = np.zeros(len(fem["M"]) - 1)
    gamma[seg - 1] = MASS_FACTOR["gamma"]
    freqs_mass = measurement_frequencies(fem, gamma)
    Z = skfem_frf(fem, ALPHA_TRUE, freqs_mass, gamma)
    rng = np.random.default_rng(MASS_SEED)
    amp = np.abs(Z) * (1 + NOISE * rng.standard_normal(Z.shape))
    write_measured(OUT / "measured_mass.csv", MeasuredFRF(
        freqs_mass, list(range(1, Z.shape[1] + 1)), amp, None,
        f"scikit-fem direct FRF at alpha {ALPHA_TRUE.tolist()}, gamma {gamma.tolist()}, {NOISE:.1%} noise, "
        f"seed {MASS_SEED}"))
    (OUT / "truth.json").write_text(json.dumps({
        "alpha": ALPHA_TRUE.tolist(), "noise": NOISE, "seed": SEED, "frequencies_hz": freqs.tolist(),
        "point_mass": {"file": "measured_point_mass.csv", "node": node,
                       "xyz_m": fem["mesh"].p[:, node].round(12).tolist(), "mass_kg": POINT_MASS["mass"],
                       "alpha": ALPHA_TRUE.tolist(), "noise": NOISE, "seed": POINT_MASS_SEED,
                       "frequencies_hz": freqs_pm.tolist()},
        "mass_factor": {"file": "measured_mass.csv", "model": "model_mass.toml",
                        "parameters": dict(zip([f"alpha_{i + 1}" for i in range(ALPHA_TRUE.size)] + [f"gamma_{seg}"],
                                               ALPHA_TRUE.tolist() + [MASS_FACTOR["gamma"]])),
                        "noise": NOISE, "seed": MASS_SEED, "frequencies_hz": freqs_mass.tolist()}}, indent=1) + "\n")
    print(f"wrote {OUT}: {len(fem['K']) - 1} segments + remainder, {fem['basis'].N} DOFs, frequencies {freqs}")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.matrix_example", __doc__)
    sys.exit(main())
