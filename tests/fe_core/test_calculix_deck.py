"""CalculiX decks: reading, writing, running ccx and its failures (fe_core/io/calculix).

References: the deck's own text (ids, sets, numbers counted by hand), and ccx itself: its natural
frequencies (*FREQUENCY), static displacements and steady-state FRF (*STEADY STATE DYNAMICS) against the
matrices it exported with *FREQUENCY, SOLVER=MATRIXSTORAGE and our reading of them.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from fe_core.io.calculix import (CcxError, CcxMissing, CcxTimeout, DeckError, node_dof_weights, read_deck,
                                 read_eigenfrequencies, read_steady_state, read_storage, run_ccx)

needs_ccx = pytest.mark.skipif(shutil.which("ccx") is None, reason="ccx not installed (apt-get install calculix-ccx)")

NX, NY, LX, LY = 4, 2, 0.4, 0.2


def plate(material_lines=("*ELASTIC", "70e9, 0.33", "*DENSITY", "2700.")) -> str:
    """A clamped aluminium S4 plate, 4 x 2 cells, elements in two sets (LEFT: x < 0.2 m, RIGHT)."""
    nid = lambda i, j: 1 + i + j * (NX + 1)  # noqa: E731
    out = ["** a test plate", "*NODE"]
    out += [f"{nid(i, j)}, {LX * i / NX}, {LY * j / NY}, 0.0" for j in range(NY + 1) for i in range(NX + 1)]
    out.append("*ELEMENT, TYPE=S4, ELSET=PLATE")
    e = 0
    for j in range(NY):
        for i in range(NX):
            e += 1
            out.append(f"{e}, {nid(i, j)}, {nid(i + 1, j)}, {nid(i + 1, j + 1)}, {nid(i, j + 1)}")
    out += ["*ELSET, ELSET=LEFT", "1, 2, 5, 6", "*ELSET, ELSET=RIGHT, GENERATE", "3, 4", "*ELSET, ELSET=RIGHT",
            "7, 8", "*NSET, NSET=FIX", "1, 6, 11", "*NSET, NSET=TIP", "15",
            "*MATERIAL, NAME=AL", *material_lines,
            "*SHELL SECTION, ELSET=LEFT, MATERIAL=AL", "0.005", "*SHELL SECTION, ELSET=RIGHT, MATERIAL=AL", "0.005",
            "*BOUNDARY", "FIX, 1, 6"]
    return "\n".join(out) + "\n"


def test_the_deck_reader_finds_nodes_elements_sets_materials_and_sections(tmp_path):
    (tmp_path / "p.inp").write_text(plate() + "*STEP\n*FREQUENCY\n4\n*END STEP\n")
    deck = read_deck(tmp_path / "p.inp")
    assert len(deck.nodes) == 15 and deck.nodes[15] == (0.4, 0.2, 0.0)
    assert len(deck.elements) == 8 and deck.elements[8] == ("S4", (9, 10, 15, 14))
    assert deck.elsets["RIGHT"] == [3, 4, 7, 8] and deck.nsets["FIX"] == [1, 6, 11]
    section = deck.section_of("right")
    assert deck.cards[section].param("ELSET") == "RIGHT"
    assert deck.number(deck.material_number(section, "*ELASTIC")) == 70e9
    assert deck.number(deck.material_number(section, "*DENSITY")) == 2700.0
    assert deck.cards[deck.first_step].keyword == "*STEP"


def test_a_written_copy_reads_back_with_the_replaced_numbers_and_new_steps(tmp_path):
    (tmp_path / "p.inp").write_text(plate() + "*STEP\n*FREQUENCY\n4\n*END STEP\n")
    deck = read_deck(tmp_path / "p.inp")
    ref = deck.material_number(deck.section_of("LEFT"), "*ELASTIC")
    text = deck.text(numbers={ref: 1.5e11}, params={deck.section_of("LEFT"): {"MATERIAL": "AL2"}},
                     extra="*MATERIAL, NAME=AL2\n*ELASTIC\n1.0, 0.3", steps="*STEP\n*STATIC\n*END STEP\n")
    (tmp_path / "q.inp").write_text(text)
    copy = read_deck(tmp_path / "q.inp")
    assert copy.nodes == deck.nodes and copy.elements == deck.elements and copy.elsets == deck.elsets
    assert copy.number(copy.material_number(copy.section_of("RIGHT"), "*ELASTIC")) == 1.5e11
    assert copy.cards[copy.section_of("LEFT")].param("MATERIAL") == "AL2"
    assert [c.keyword for c in copy.cards[copy.first_step:]] == ["*STEP", "*STATIC", "*END STEP"]


def test_includes_are_followed_inside_the_models_folder_and_refused_outside(tmp_path):
    model = tmp_path / "model"
    (model / "parts").mkdir(parents=True)
    (model / "parts" / "mesh.inp").write_text(plate())
    (model / "main.inp").write_text("** main\n*INCLUDE, INPUT=parts/mesh.inp\n")
    assert len(read_deck(model / "main.inp").nodes) == 15
    (tmp_path / "outside.inp").write_text(plate())
    (model / "bad.inp").write_text("** main\n\n*INCLUDE, INPUT=../outside.inp\n")
    with pytest.raises(DeckError, match=r"bad\.inp:3: \*INCLUDE of .*outside\.inp.* is outside the model's folder"):
        read_deck(model / "bad.inp")
    assert len(read_deck(model / "bad.inp", allowed=[tmp_path]).nodes) == 15
    (model / "missing.inp").write_text("*INCLUDE, INPUT=nothere.inp\n")
    with pytest.raises(DeckError, match=r"missing\.inp:1: \*INCLUDE file .*nothere\.inp.* does not exist"):
        read_deck(model / "missing.inp")


def test_a_set_naming_an_unknown_set_is_refused_with_file_and_line(tmp_path):
    (tmp_path / "p.inp").write_text(plate() + "*ELSET, ELSET=BAD\nLEFT, NOSUCH\n")
    with pytest.raises(DeckError, match=r"p\.inp:\d+: \*ELSET: 'NOSUCH' is neither an id nor a defined set"):
        read_deck(tmp_path / "p.inp")


def test_a_missing_ccx_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    (tmp_path / "p.inp").write_text(plate())
    with pytest.raises(CcxMissing, match="apt-get install calculix-ccx"):
        run_ccx(tmp_path, "p", timeout=10)


@needs_ccx
def test_a_deck_ccx_rejects_quotes_its_error_lines(tmp_path):
    (tmp_path / "p.inp").write_text(plate().replace("FIX, 1, 6", "NOSUCH, 1, 6") + "*STEP\n*STATIC\n*END STEP\n")
    with pytest.raises(CcxError) as info:
        run_ccx(tmp_path, "p", timeout=60)
    assert str(info.value).startswith(f"{tmp_path / 'p.inp'}: ccx rejected the deck")
    assert "*ERROR" in str(info.value) and "node set NOSUCH" in str(info.value)


@needs_ccx
def test_a_run_past_its_time_limit_is_stopped(tmp_path):
    # a 60 x 60 S4 plate's 40 modes take well over 0.05 s
    n = 60
    nid = lambda i, j: 1 + i + j * (n + 1)  # noqa: E731
    lines = ["*NODE"] + [f"{nid(i, j)}, {i / n}, {j / n}, 0" for j in range(n + 1) for i in range(n + 1)]
    lines += ["*ELEMENT, TYPE=S4, ELSET=P"] + [f"{1 + i + j * n}, {nid(i, j)}, {nid(i + 1, j)}, {nid(i + 1, j + 1)}, "
                                              f"{nid(i, j + 1)}" for j in range(n) for i in range(n)]
    lines += ["*MATERIAL, NAME=A", "*ELASTIC", "70e9, 0.3", "*DENSITY", "2700", "*SHELL SECTION, ELSET=P, MATERIAL=A",
              "0.01", "*BOUNDARY", "1, 1, 6", f"{n + 1}, 1, 6", "*STEP", "*FREQUENCY", "40", "*END STEP"]
    (tmp_path / "big.inp").write_text("\n".join(lines) + "\n")
    with pytest.raises(CcxTimeout, match=r"big\.inp: ccx ran past its time limit of 0\.05 s"):
        run_ccx(tmp_path, "big", timeout=0.05)


def _matrices(tmp_path):
    (tmp_path / "m.inp").write_text(plate() + "*STEP\n*FREQUENCY, SOLVER=MATRIXSTORAGE\n*END STEP\n")
    run_ccx(tmp_path, "m", timeout=60, expect=(".sti", ".mas", ".dof"))
    return read_storage(tmp_path, "m")


@needs_ccx
def test_the_exported_matrices_give_ccxs_own_natural_frequencies(tmp_path):
    K, M, labels = _matrices(tmp_path)
    (tmp_path / "f.inp").write_text(plate() + "*STEP\n*FREQUENCY\n6\n*END STEP\n")
    run_ccx(tmp_path, "f", timeout=60)
    theirs = read_eigenfrequencies(tmp_path / "f.dat")
    lam = np.sort(spla.eigsh(K.tocsc(), k=6, M=M.tocsc(), sigma=0, return_eigenvectors=False))
    ours = np.sqrt(lam) / (2 * np.pi)
    assert theirs.size == 6
    np.testing.assert_allclose(ours, theirs, rtol=2e-6)  # ccx prints 7 digits


@needs_ccx
def test_a_shell_nodes_displacement_is_the_mean_of_its_rows_as_ccx_reports_it(tmp_path):
    """Static: K u = f with the load shared among the node's rows, against ccx's *STATIC displacements."""
    K, M, labels = _matrices(tmp_path)
    f = np.zeros(K.shape[0])
    for node, d, value in ((15, 3, 1.0), (10, 2, 2.0)):
        rows, w = node_dof_weights(labels, node, d)
        f[rows] += value * w
    u = np.linalg.solve(K.toarray(), f)
    (tmp_path / "s.inp").write_text(plate() + "*NSET, NSET=OUT\n2, 10, 15\n*STEP\n*STATIC\n*CLOAD\n15, 3, 1.0\n"
                                              "10, 2, 2.0\n*NODE PRINT, NSET=OUT\nU\n*END STEP\n")
    run_ccx(tmp_path, "s", timeout=60)
    text = (tmp_path / "s.dat").read_text().split("displacements")[1].splitlines()[2:5]
    theirs = {int(r.split()[0]): np.array([float(v) for v in r.split()[1:]]) for r in text}
    for node in (2, 10, 15):
        ours = np.array([w @ u[rows] for rows, w in (node_dof_weights(labels, node, d) for d in (1, 2, 3))])
        scale = np.abs(theirs[node]).max()
        np.testing.assert_allclose(ours, theirs[node], atol=2e-6 * scale)  # 7 printed digits


@needs_ccx
def test_the_steady_state_reader_returns_ccxs_complex_response(tmp_path):
    """ccx's modal FRF (20 modes, Rayleigh damping) against a direct solve with its exported matrices."""
    K, M, labels = _matrices(tmp_path)
    a, b = 10.0, 1e-5
    (tmp_path / "d.inp").write_text(plate() + "*NSET, NSET=OUT\n10, 15\n*STEP\n*FREQUENCY, STORAGE=YES\n20\n"
                                    "*CLOAD\n15, 3, 0.\n*END STEP\n*STEP\n*STEADY STATE DYNAMICS\n20., 40., 3, 1.\n"
                                    f"*MODAL DAMPING, RAYLEIGH\n,,{a},{b}\n*CLOAD\n15, 3, 1.0\n"
                                    "*NODE PRINT, NSET=OUT\nU\n*END STEP\n")
    run_ccx(tmp_path, "d", timeout=60)
    freqs, disp = read_steady_state(tmp_path / "d.dat")
    assert freqs[0] == 20.0 and freqs[-1] == 40.0 and sorted(disp) == [10, 15]
    rows, w = node_dof_weights(labels, 15, 3)
    f = np.zeros(K.shape[0])
    f[rows] = w
    Kd, Md = K.toarray(), M.toarray()
    for k, fr in enumerate(freqs):
        om = 2 * np.pi * fr
        u = np.linalg.solve(Kd - om**2 * Md + 1j * om * (a * Md + b * Kd), f)
        for node in (10, 15):
            r, wn = node_dof_weights(labels, node, 3)
            ours = wn @ u[r]
            # modal truncation (20 of 147 modes) and 7 printed digits
            assert abs(ours - disp[node][k, 2]) < 2e-3 * abs(ours), (fr, node, ours, disp[node][k, 2])
