"""Bad input with a CalculiX deck (``solver = "calculix"``): ``python -m flows.update`` exits 2 naming the file
(and the key or line), before any FE run of the update, and writes no run folder."""

from __future__ import annotations

import shutil

import pytest

from flows import update
from flows.config import REPO

EXAMPLE = REPO / "data" / "examples" / "shell_panel"
needs_ccx = pytest.mark.skipif(shutil.which("ccx") is None, reason="ccx not installed (apt-get install calculix-ccx)")


def _run(tmp_path, capsys, toml_edit=None, deck_edit=None) -> str:
    model = tmp_path / "model"
    model.mkdir()
    toml = (EXAMPLE / "model.toml").read_text()
    deck = (EXAMPLE / "panel.inp").read_text()
    (model / "model.toml").write_text(toml_edit(toml) if toml_edit else toml)
    (model / "panel.inp").write_text(deck_edit(deck) if deck_edit else deck)
    runs = tmp_path / "runs"
    code = update.main(["--model", str(model / "model.toml"), "--measured", str(EXAMPLE / "measured.csv"),
                        "--run-id", "x", "--runs-dir", str(runs)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    assert not (runs / "x").exists()
    return err


@pytest.fixture(autouse=True)
def fresh_cache(tmp_path, monkeypatch):
    """No matrices cached from other runs: every case reaches ccx."""
    monkeypatch.setenv("FE_CALCULIX_CACHE", str(tmp_path / "cache"))


def test_ccx_not_installed(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    err = _run(tmp_path, capsys)
    assert f"{tmp_path / 'model' / 'model.toml'}: key 'deck'" in err
    assert "apt-get install calculix-ccx" in err


@needs_ccx
def test_a_deck_ccx_rejects_quotes_its_error_lines(tmp_path, capsys):
    bad = "*BOUNDARY\nNOSUCH, 1, 6\n*NSET, NSET=SUSPENSION"           # the example is free: no *BOUNDARY of its own
    err = _run(tmp_path, capsys, deck_edit=lambda d: d.replace("*NSET, NSET=SUSPENSION", bad))
    assert f"{tmp_path / 'model' / 'model.toml'}: key 'deck'" in err
    assert "ccx rejected the deck" in err and "*ERROR reading *BOUNDARY: node set NOSUCH" in err


@needs_ccx
def test_a_solver_run_past_its_time_limit(tmp_path, capsys):
    err = _run(tmp_path, capsys, toml_edit=lambda t: t.replace("solver_timeout = 120.0", "solver_timeout = 0.005"))
    assert "ccx ran past its time limit of 0.005 s" in err


@pytest.mark.parametrize("edit, needle", [
    (lambda t: t.replace('set = "TIP_HIGH"', 'set = "NOPE"'), "key 'segments[3].set': *ELSET 'NOPE' is not in the deck"),
    (lambda t: t.replace('nset = "TIP_CORNER"', 'nset = "NOPE"'),
     "key 'excitations[0].nset': *NSET 'NOPE' is not in the deck"),
    (lambda t: t.replace('nset = "TIP_CORNER"', 'nset = "SUSPENSION"'),
     "key 'excitations[0].nset': *NSET 'SUSPENSION' has 4 nodes; a sensor or excitation point needs a set of one node"),
    (lambda t: t.replace("node = ", "node = 99999 #", 1), "key 'sensors[0].node': node 99999 is not a node of the deck"),
    # a segment is a number of the deck (its section's modulus): a set with no section names none
    (lambda t: t.replace('set = "TIP_HIGH"', 'set = "PANEL"'),
     "key 'segments[3].set': ", ),
], ids=["elset", "nset", "nset-not-one-node", "node", "no-number"])
def test_names_absent_from_the_deck(tmp_path, capsys, edit, needle):
    err = _run(tmp_path, capsys, toml_edit=edit)
    assert f"{tmp_path / 'model' / 'model.toml'}: {needle}" in err


def test_a_set_with_no_section_names_the_deck(tmp_path, capsys):
    err = _run(tmp_path, capsys, toml_edit=lambda t: t.replace('set = "TIP_HIGH"', 'set = "PANEL"'))
    assert "no section card (*SOLID/*SHELL/*BEAM SECTION) has ELSET=PANEL" in err


def test_a_material_without_a_modulus_names_its_line(tmp_path, capsys):
    err = _run(tmp_path, capsys, deck_edit=lambda d: d.replace("*ELASTIC\n7e+10, 0.33\n", ""))
    assert f"{tmp_path / 'model' / 'panel.inp'}:" in err and "material ALU has no *ELASTIC card" in err


def test_an_include_outside_the_models_folder(tmp_path, capsys):
    (tmp_path / "secret.inp").write_text("*NODE\n1, 0, 0, 0\n")
    err = _run(tmp_path, capsys, deck_edit=lambda d: "*INCLUDE, INPUT=../secret.inp\n" + d)
    assert f"{tmp_path / 'model' / 'panel.inp'}:1: *INCLUDE of" in err and "outside the model's folder" in err
