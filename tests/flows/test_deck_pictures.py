"""The report's mesh pictures of a solver deck (solver = "calculix"): the shells coloured by segment and by
the updated factors, the sensors where the deck's nodes are, and the updated model's mode shapes.

Reference: the deck itself (its S8R elements, *ELSETs and node coordinates, read by meshio as well) and
ccx's eigenfrequencies of the same deck (*FREQUENCY)."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

pytestmark = pytest.mark.skipif(shutil.which("ccx") is None, reason="ccx not installed (apt-get install calculix-ccx)")

ALPHA = np.array([0.1, -0.1, 0.2, 0.0])


@pytest.fixture(scope="module")
def panel(tmp_path_factory):
    """The shell example's suspended panel (benchmarks/make/shell_panel.py) on an 8 x 8 S8R mesh."""
    from benchmarks.make import shell_panel
    from fe_core.io import read_model

    folder = tmp_path_factory.mktemp("deck")
    shell_panel.write_model(folder, (8, 8))
    return folder, read_model(folder / "model.toml")


def test_the_deck_view_draws_every_shell_of_its_segment_and_the_sensors_at_their_nodes(panel):
    import meshio

    from tasks.report.deck_mesh import DeckMeshView

    folder, model = panel
    view = DeckMeshView(model)
    # meshio's own reading of the deck's mesh (Abaqus format; it knows no SPRING1, which follow the materials)
    (folder / "mesh.inp").write_text((folder / "panel.inp").read_text().split("*MATERIAL")[0])
    grid = meshio.read(folder / "mesh.inp")
    quads = np.vstack([c.data for c in grid.cells if c.type == "quad8"])
    assert view.n_cells == len(quads) == 64 and view.polygons.shape == (64, 8, 3)
    # the polygons run around each S8R's edge: corner, mid-side, corner, ...; corners are meshio's corners
    np.testing.assert_allclose(np.sort(view.polygons[:, ::2].reshape(-1, 3), axis=0),
                               np.sort(grid.points[quads[:, :4]].reshape(-1, 3), axis=0))
    sets = {name: len(np.concatenate(list(v.values()) if isinstance(v, dict) else v))
            for name, v in grid.cell_sets.items()}
    assert [int(np.sum(view.segment == k)) for k in range(4)] == [sets[s] for s in
                                                                 ("ROOT_LOW", "ROOT_HIGH", "TIP_LOW", "TIP_HIGH")]
    assert view.skipped == {"SPRING1": 12}                   # the suspension: 4 corners x 3 directions
    toml = (folder / "model.toml").read_text()
    nodes = [int(line.split("=")[1]) for line in toml.splitlines() if line.startswith("node =")]
    view_ids = model.deck_view.node_ids
    index = {int(n): i for i, n in enumerate(view_ids)}
    for j, node in enumerate(nodes):
        arrows = view.arrows(model, model.outputs.tocsc()[:, j])
        assert list(view_ids[arrows.nodes]) == [node]
        np.testing.assert_allclose(arrows.positions[0], view.points[index[node]])
        assert np.isclose(np.max(np.abs(arrows.directions[0])), 1.0)


def test_the_report_of_a_deck_model_has_its_mesh_factors_and_mode_shapes(panel, tmp_path):
    from fe_core.io.calculix import read_deck, read_eigenfrequencies, run_ccx
    from tasks.report.deck_mesh import MODES_PNG
    from tasks.report.mesh import FACTORS_PNG, SEGMENTS_PNG, mesh_section

    folder, model = panel
    data = SimpleNamespace(config={"model": str(folder / "model.toml")}, model=model, root=tmp_path,
                           names=model.parameter_names, best=lambda: (-1, ALPHA, 0.0),
                           measured=pd.DataFrame({"frequency_hz": [60.0, 90.0], "sensor": [1, 1],
                                                  "amplitude": [1.0, 1.0]}), frequencies=np.array([60.0, 90.0]))
    section = mesh_section(data, tmp_path / "report")
    names = [path.name for path, _ in section.figures]
    assert names == [SEGMENTS_PNG, FACTORS_PNG, MODES_PNG]
    for path, _ in section.figures:
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 20000
    assert "solver deck's mesh: 64 cells" in section.paragraphs[0] and "12 SPRING1" in section.paragraphs[0]
    table = section.tables[0][1]
    np.testing.assert_allclose(table["alpha (updated)"], ALPHA)
    # the modes drawn: ccx's own flexible modes of the deck with the factors as moduli, from 30 Hz up
    caption = section.figures[2][1]
    drawn = [float(f) for f in caption.split("(")[1].split(" Hz")[0].split(", ")]
    deck = read_deck(folder / "panel.inp")
    cards, params = [], {}
    for k, (s, a) in enumerate(zip(("ROOT_LOW", "ROOT_HIGH", "TIP_LOW", "TIP_HIGH"), ALPHA)):
        cards.append(f"*MATERIAL, NAME=M{k}\n*ELASTIC\n{7e10 * (1 + float(a))!r}, 0.33\n*DENSITY\n2700.")
        params[deck.section_of(s)] = {"MATERIAL": f"M{k}"}
    (tmp_path / "f.inp").write_text(deck.text(params=params, extra="\n".join(cards),
                                              steps="*STEP\n*FREQUENCY\n10\n*END STEP\n"))
    run_ccx(tmp_path, "f", timeout=120)
    theirs = read_eigenfrequencies(tmp_path / "f.dat")
    np.testing.assert_allclose(drawn, theirs[theirs >= 30.0][:len(drawn)], atol=0.006)   # printed to 0.01 Hz
    assert len(drawn) == 4
