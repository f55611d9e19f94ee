"""One held-out case from its seed: draw it, build the data structure with its effect, solve, simulate the test,
write ``measured.csv`` and ``truth.json``.

Sizes: a point mass of ``share`` (2-8 %) of the structure's mass; a mount of ``ratio`` (0.2-0.8) times the
held structure's static stiffness at that node along the axis it is most compliant in; a damaged patch (the
tool's ``node N r2``) with ``beta`` in [-0.7, -0.3] (its share of its segment's stiffness is recorded); a mass
layer of 3-8 % of the mass; a flexible joint whose layer is ``1 / ratio`` times softer than the member's depth
of the same material (``ratio`` 0.003-0.03, :func:`_joint`). Places: a surface corner node of the tool's mesh
(any node of the deck) at least ``CLEAR`` of the structure's size from every held node; the data carry the
effect at their own nearest vertex (the frame and the deck share the tool's nodes).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from benchmarks.make.cases import deck as dk
from benchmarks.make.cases import effects as fx
from benchmarks.make.cases import fem_data as fd
from benchmarks.make.cases import noise

REPO = Path(__file__).resolve().parents[3]
ROOT = REPO / "data" / "cases" / "held_out"
CLEAR = 0.15
BAND_MODES = (6, 10)


def draw(spec: dict, n_segments: int) -> dict:
    """Everything the seed decides, in one fixed order (whatever the kind, so a kind does not shift the rest)."""
    rng = np.random.default_rng(spec["seed"])
    d = {"alpha": rng.uniform(-0.3, 0.3, n_segments), "place": rng.uniform(), "share": rng.uniform(0.02, 0.08),
         "ratio": rng.uniform(0.2, 0.8), "beta": rng.uniform(-0.7, -0.3), "layer_share": rng.uniform(0.03, 0.08),
         "joint_ratio": 10 ** rng.uniform(np.log10(0.003), np.log10(0.03)),
         "band_modes": int(rng.integers(BAND_MODES[0], BAND_MODES[1] + 1)),
         "relative": rng.uniform(0.005, 0.02), "floor": 10 ** rng.uniform(-4, -3), "force": rng.uniform(0.001, 0.005),
         "averages": int(rng.integers(5, 11)), "fewer": int(rng.integers(1, 3))}
    d["fewer_channels"] = rng.permutation(64)      # the first ``fewer`` below the channel count
    d["noise_seed"] = int(rng.integers(2**31))
    return d


def _away(points, held_points, size) -> np.ndarray:
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(held_points).query(points)
    return dist >= CLEAR * size


# -- a solid structure ------------------------------------------------------------------------------------
def _solid(spec, s, dr, info) -> dict:
    from benchmarks.make.cases.modelfile import surface_nodes

    d = fd.data_model(s)
    alpha = dr["alpha"]
    kind = spec["kind"]
    held = s["support"](s["model_nodes"])
    out = {"alpha": alpha, "d": d, "extra_K": None, "extra_M": None, "effect": {"kind": kind}}
    mass = fd.total_mass(d)
    if kind in ("point_mass", "mount"):
        nodes = surface_nodes(s["model_cells"])
        nodes = nodes[_away(s["model_nodes"][nodes], s["model_nodes"][held], s["size_m"])]
        m = int(nodes[int(dr["place"] * nodes.size)])
        v = int(np.argmin(np.linalg.norm(s["data_nodes"] - s["model_nodes"][m], axis=1)))
        e = {"node": m, "location": f"node {m}", "xyz_m": s["data_nodes"][v].tolist(), "data_vertex": v,
             "model_node_xyz_m": s["model_nodes"][m].tolist()}
        if kind == "point_mass":
            e.update(value=dr["share"] * mass, unit="kg", share_of_mass=dr["share"])
            out["extra_M"] = fx.point_mass(d, v, e["value"])
        else:
            K, _ = fd.assembled(d, alpha)
            free_index = np.full(d["basis"].N, -1)
            free_index[d["free"]] = np.arange(d["free"].size)
            compliance = fd.static_compliance(fd.condensed(K, K, d["free"])[0], free_index, d["basis"].nodal_dofs[:, v])
            axis = int(np.argmax(compliance))
            k_static = 1.0 / compliance[axis]
            e.update(value=dr["ratio"] * k_static, unit="N/m", axis="xyz"[axis], ratio_of_static=dr["ratio"],
                     static_stiffness=k_static, library_kind="grounded_spring" + ("" if axis == 2 else "_" + "xyz"[axis]))
            out["extra_K"] = fx.mount(d, v, axis, e["value"])
        out["effect"].update(e)
    elif kind == "patch":
        corners = np.unique(s["model_cells"][:, :4 if s["model_cells"].shape[1] in (4, 10) else 8])
        corners = corners[_away(s["model_nodes"][corners], s["model_nodes"][held], s["size_m"])]
        m = int(corners[int(dr["place"] * corners.size)])
        model_patch = fx.patch_cells(s["model_cells"], m)
        data_patch = fx.cells_inside(s, model_patch)
        seg_of_data = d["segment"][data_patch]
        main = int(np.bincount(seg_of_data[seg_of_data >= 0]).argmax())
        vol = _volumes(s, d)
        share = -dr["beta"] * vol[data_patch].sum() / vol[d["segment"] == main].sum()
        out["extra_K"] = fx.patch_stiffness(s, d, alpha, data_patch, dr["beta"])
        out["effect"].update(node=m, location=f"node {m} r2", value=dr["beta"], unit="-",
                             xyz_m=fx.patch_centre(s["model_nodes"], s["model_cells"], model_patch).tolist(),
                             model_cells=int(model_patch.size), data_cells=int(data_patch.size),
                             segment=s["segments"][main], share_of_segment_stiffness=float(share))
    elif kind == "mass_layer":
        M, cells = fx.mass_layer(s, d, dr["layer_share"] * mass)
        out["extra_M"] = M
        c = fx.corner_centroids(s["data_nodes"], s["data_cells"][cells])
        segs = sorted({s["segments"][i] for i in d["segment"][cells]})
        out["effect"].update(value=dr["layer_share"] * mass, unit="kg", share_of_mass=dr["layer_share"],
                             region=list(s["layer"]), xyz_m=c.mean(axis=0).tolist(), data_cells=int(cells.size),
                             segments=segs, description=f"a non-structural mass layer over {len(segs)} segments")
    elif kind == "joint":
        out.update(_joint(s, d, dr))
    elif kind != "none":
        raise ValueError(kind)
    out["mass"] = mass
    return out


def _volumes(s, d) -> np.ndarray:
    """Each data cell's volume, m^3 (its mass matrix's x-sum over the density)."""
    from skfem import Functional

    @Functional
    def one(w):
        return 1.0 + 0.0 * w.x[0]

    from skfem import Basis
    b = Basis(d["basis"].mesh, d["basis"].elem, intorder=2)
    return one.elemental(b)


def _joint(s, d, dr) -> dict:
    """The joint: the data mesh cut at the interface, reassembled, tied by a compliant layer whose stiffness per
    area is ``joint_ratio * E / depth`` (``depth`` the joined member's depth: 30 mm)."""
    s2, iface = fx.cut(s)
    d2 = fd.data_model(s2, cache=False)
    E, nu, _ = s["material"]
    per_area = dr["joint_ratio"] * E / 0.03
    area = s["joint"]["area"]
    Kj, places = fx.joint_springs(s2, d2, per_area, nu, area)
    return {"d": d2, "extra_K": Kj, "effect": {"kind": "joint", "value": per_area, "unit": "N/m^3",
            "ratio": dr["joint_ratio"], "interface_vertices": int(iface.size), "dof_places": places, "area_m2": area,
            "xyz_m": s["data_nodes"][iface].mean(axis=0).tolist(), "description": s["joint"]["description"]}}


# -- the deck ------------------------------------------------------------------------------------------------
def _deck(spec, dr) -> dict:
    kind = spec["kind"]
    alpha = dr["alpha"]
    K, M, outputs, load, labels, coords = dk.matrices(alpha)
    ux = (labels[:, 1] == 1).astype(float)
    mass = float(ux @ (M @ ux))
    effect = {"kind": kind}
    ccx_effect = None
    if kind in ("point_mass", "mount"):
        ids, _, model_coords = dk.mesh(dk.MODEL_MESH)
        nodes = np.array([i for i, p in model_coords.items() if p[0] >= CLEAR * dk.L])
        m = int(nodes[int(dr["place"] * nodes.size)])
        xyz = model_coords[m]
        fine = dk.node_of(xyz, dk.DATA_MESH)
        effect.update(node=m, location=f"node {m}", xyz_m=list(xyz), data_node=fine)
        if kind == "point_mass":
            effect.update(value=dr["share"] * mass, unit="kg", share_of_mass=dr["share"])
            ccx_effect = {"kind": "point_mass", "node": fine, "value": effect["value"]}
        else:
            compliance = _deck_compliance(K, labels, fine)
            axis = int(np.argmax(compliance))
            k_static = 1.0 / compliance[axis]
            effect.update(value=dr["ratio"] * k_static, unit="N/m", axis="xyz"[axis], ratio_of_static=dr["ratio"],
                          static_stiffness=k_static,
                          library_kind="grounded_spring" + ("" if axis == 2 else "_" + "xyz"[axis]))
            ccx_effect = {"kind": f"grounded_spring_{'xyz'[axis]}", "node": fine, "value": effect["value"]}
    elif kind == "mass_layer":
        region = DECK_LAYER
        cells = dk.region_cells(region, dk.DATA_MESH)
        area = cells * (dk.L / dk.DATA_MESH[0]) * (dk.H / dk.DATA_MESH[1])     # web cells of the data mesh
        layer_mass = dr["layer_share"] * mass
        factor = 1.0 + layer_mass / (dk.RHO * dk.T * area)
        ccx_effect = {"kind": "mass_layer", "region": region, "factor": factor}
        effect.update(value=layer_mass, unit="kg", share_of_mass=dr["layer_share"], region=list(region),
                      data_cells=cells, density_factor=factor,
                      xyz_m=[(region[0] + region[1]) / 2, 0.0, (region[4] + region[5]) / 2],
                      segments=["WEB_ROOT", "WEB_TIP"], description="a non-structural mass layer on the web over "
                                                                    "x 0.25-0.55 m (across both web segments)")
    elif kind != "none":
        raise ValueError(f"{kind} is not made on the deck")
    base = (K, M, outputs, load)
    with_effect = base if ccx_effect is None else dk.matrices(alpha, ccx_effect)[:4]
    return {"alpha": alpha, "effect": effect, "mass": mass, "base": base, "with": with_effect}


#: The deck's mass layer: the web (y = 0) over x 0.25-0.55 m, the whole height.
DECK_LAYER = (0.25, 0.55, -1e-6, 1e-6, -1e-6, dk.H + 1e-6)


def _deck_compliance(K, labels, node) -> np.ndarray:
    """Static compliance of a deck node along x, y, z (a load shared by its rows, the mean of their motion)."""
    factor = fd.Factor(K)
    try:
        out = []
        for c in range(3):
            rows = np.flatnonzero((labels[:, 0] == node) & (labels[:, 1] == c + 1))
            e = np.zeros(K.shape[0])
            e[rows] = 1.0 / rows.size
            out.append(float(e @ factor(e)))
    finally:
        factor.free()
    return np.array(out)
