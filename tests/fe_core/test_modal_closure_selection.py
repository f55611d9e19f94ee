"""The closure on modal residuals with several effects: forward selection (fe_core/modal_update/closure.py).

Data: a clamped steel strip (500 x 60 x 10 mm, hex8, 3 stiffness segments) at known factors, with a point
mass of 0.12 kg (5 % of the strip) on the top node at x = 400 mm, y = +30 mm and a grounded z-spring of
30 kN/m at x = 200 mm, y = -30 mm, both written into the matrices here by hand (not through the effect
classes the closure uses); its six modes with z motion at 20 test DOFs, 0.2 % frequency and 2 % shape noise.
The fitted model lacks both. The closure must add the mass, then the spring, each refitted jointly with the
factors, and end at the noise; its FE runs are logged with the stage that asked for them.
"""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.benchmark import STEEL
from fe_core.mesh import Block, mesh_blocks
from fe_core.model import build_model
from fe_core.modal_update import ModalResidual, fit_modes
from fe_core.modal_update.closure import modal_closure
from fe_core.solvers.modal import eigenmodes

L, W, T = 0.5, 0.06, 0.01
ELEMENT = L / 20
TRUTH = np.array([0.1, -0.15, 0.05])
MASS, MASS_AT = 0.12, (0.4, 0.03, T)
SPRING, SPRING_AT = 3e4, (0.2, -0.03, T)


@pytest.fixture(scope="module")
def case():
    mesh = mesh_blocks([Block(x=np.linspace(0, L, 21), y=np.linspace(-W / 2, W / 2, 4), z=np.linspace(0, T, 2),
                              name="strip")])
    cx = mesh.centroids[:, 0]
    segments = {f"s{k + 1}": np.flatnonzero((cx > k * L / 3) & (cx < (k + 1) * L / 3)) for k in range(3)}
    mesh.add_node_set("top", mesh.nodes_where(z=T))
    sensors = [mesh.nearest_node((x, y, T)) for x in np.linspace(0.05, L, 10) for y in (-W / 2, W / 2)]
    model = build_model(mesh, STEEL, segments, fixed_nodes=mesh.nodes_where(x=0.0), sensor_nodes=sensors,
                        damping=(0.0, 0.0))
    alpha, _ = model.factors(TRUTH)
    K, M = model.stiffness(alpha).tolil(), model.mass().tolil()

    def rows(node):
        return model.free_dofs.searchsorted([3 * node, 3 * node + 1, 3 * node + 2])

    for r in rows(mesh.nearest_node(MASS_AT)):
        M[r, r] += MASS
    z = rows(mesh.nearest_node(SPRING_AT))[2]
    K[z, z] += SPRING
    f, v = eigenmodes(K.tocsr(), M.tocsr(), 8)
    psi = (model.outputs.T @ v).T
    keep = [i for i in range(8) if np.linalg.norm(psi[i]) > 0.1 * np.linalg.norm(v[:, i])]  # z modes, not in-plane
    rng = np.random.default_rng(4)
    fn = f[keep] * (1 + 0.002 * rng.standard_normal(len(keep)))
    rms = np.sqrt(np.mean(psi[keep] ** 2, axis=1, keepdims=True))
    sn = psi[keep] + 0.02 * rms * rng.standard_normal(psi[keep].shape)
    residual = ModalResidual(model, model.outputs, fn, sn, 0.002, 0.02, len(keep) + 6, 0.6)
    lower, upper = np.full(3, -0.9), np.full(3, 1.0)
    residual.set_active(np.zeros(3))
    fit = fit_modes(residual, lower, upper, n_starts=1)
    runs = len(residual.history)
    out = modal_closure(residual, fit.theta, lower, upper)
    return residual, fit, out, runs


def test_forward_selection_adds_the_mass_then_the_spring_and_ends_at_the_noise(case):
    residual, fit, out, _ = case
    assert out["before"]["structured"] and not out["after"]["structured"], (out["before"], out["after"])
    assert out["verdict"] == "explained"
    assert [a["effect"] for a in out["added"]] == ["point_mass", "grounded_spring"], out["rounds"]
    mass, spring = out["added"]
    assert np.linalg.norm(np.subtract(mass["position_m"], MASS_AT)) < 0.5 * ELEMENT  # the node itself
    assert abs(mass["value"] - MASS) < 3 * mass["sd"] + 0.02 * MASS, mass
    # the spring: within one element of its node (neighbouring nodes fit nearly as well, chi2 within 1)
    assert np.linalg.norm(np.subtract(spring["position_m"], SPRING_AT)) < 1.01 * ELEMENT, spring
    assert 0.5 * SPRING < spring["value"] < 2 * SPRING, spring
    # each addition lowers the extended BIC, and the second is refitted jointly with the first and the factors
    assert all(r["checked"] and min(c["delta_bic"] for c in r["checked"]) < 0 for r in out["rounds"][:2])
    theta = np.asarray(out["theta"])
    assert np.all(np.abs(theta - TRUTH) < np.abs(fit.theta - TRUTH)), (theta, fit.theta)
    assert np.all(np.abs(theta - TRUTH) < 0.01)


def test_the_closure_fe_runs_are_logged_by_stage(case):
    residual, _, out, runs = case
    closure = residual.history[runs:]
    assert len(closure) == out["fe_runs"] > 0
    stages = {h["stage"].split(":")[0] for h in closure}
    assert stages == {"closure-1", "closure-2"}  # at the noise after the second: no third round
    assert any("grounded_spring" in h["stage"] for h in closure)
