"""The tool's model of a solid structure: ``<name>.vtu`` (the model mesh; 0/1 cell-data arrays for the segments,
a point-data array ``support`` for the held nodes: the sets :mod:`fe_core.io.mesh_file` reads) and ``model.toml``
(docs/model-files.md), as an engineer would write them: nominal material, the segments' stiffness factors in
[-0.5, 0.5], the supports, the sensors and the hammer by point."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.make.cases.solids import corner_centroids


def surface_nodes(cells: np.ndarray) -> np.ndarray:
    """Corner nodes on the boundary (faces used by one cell), sorted."""
    if cells.shape[1] in (4, 10):
        faces = np.concatenate([cells[:, f] for f in ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3))])
    else:
        faces = np.concatenate([cells[:, f] for f in ((0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5),
                                                     (2, 3, 7, 6), (3, 0, 4, 7))])
    key = np.sort(faces, axis=1)
    _, index, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return np.unique(faces[index[counts == 1]])


def write_solid_model(s: dict, folder: Path, damping) -> dict:
    """Write ``<name>.vtu`` and ``model.toml`` of a solid structure into ``folder``; returns facts for
    ``structure.json`` (DOFs, cells, held nodes)."""
    import meshio

    folder.mkdir(parents=True, exist_ok=True)
    nodes, cells = s["model_nodes"], s["model_cells"]
    seg = s["segment_of"](corner_centroids(nodes, cells))
    cell_data = {name: [(seg == i).astype(np.int32)] for i, name in enumerate(s["segments"])}
    support = s["support"](nodes).astype(np.int32)
    meshio.write(folder / f"{s['name']}.vtu",
                 meshio.Mesh(nodes, [(s["model_cell_type"], cells)], cell_data=cell_data,
                             point_data={"support": support}), binary=True, compression="zlib")
    E, nu, rho = s["material"]
    h = s["sizes"][0] if s.get("sizes") else 0.015
    lines = [f"# {s['description']}.",
             "# Written by python -m benchmarks.make.cases (issue 40's held-out cases; docs/results/held-out.md).",
             'units = "SI"', f'mesh = "{s["name"]}.vtu"', f"point_tolerance = {h:.4g}   # m: the model's element size",
             "", "[damping]", f"a = {damping[0]!r}", f"b = {damping[1]!r}", ""]
    if s["model_cell_type"] == "hexahedron":
        lines += ["[elements.hexahedron]", 'formulation = "incompatible"', ""]
    lines += ["[[materials]]", f"E = {E!r}", f"nu = {nu!r}", f"rho = {rho!r}", ""]
    for name in s["segments"]:
        lines += ["[[segments]]", f'set = "{name}"', "bounds = [-0.5, 0.5]", ""]
    lines += [f"# {s['support_text']}", "[[supports]]", 'nodes = "support"', 'fix = ["x", "y", "z"]', ""]
    for name, point, direction in s["sensors"]:
        lines += ["[[sensors]]", f'name = "{name}"', f"point = {[float(v) for v in point]}",
                  f"direction = {[float(v) for v in direction]}", ""]
    name, point, direction = s["excitation"]
    lines += ["[[excitations]]", f'name = "{name}"', f"point = {[float(v) for v in point]}",
              f"direction = {[float(v) for v in direction]}", ""]
    (folder / "model.toml").write_text("\n".join(lines))
    return {"model_dofs": int(3 * len(nodes)), "model_cells": int(len(cells)), "held_nodes": int(support.sum()),
            "cell_type": s["model_cell_type"]}
