"""Measured modes: UFF dataset 55 and the CSV table read back, the complex-to-real rule, recognition of a
modal file, matching to a model by test_node, and bad input naming the dataset or line."""

from __future__ import annotations

import numpy as np
import pytest

from tasks.io.measured import MeasuredDataError
from tasks.io.measured.modes import (MeasuredModes, is_modal_file, read_modes, real_mode, write_csv,
                                     write_uff55)

SHAPES = np.array([[1.0, 2.0, 3.0], [3.0, -1.0, 0.5]])


def _modes(**changes) -> MeasuredModes:
    values = dict(frequencies_hz=np.array([100.0, 250.0]), damping=np.array([0.01, 0.02]), shapes=SHAPES.copy(),
                  dofs=["1:+z", "2:+z", "3:+x"], names=["mode 1", "mode 2"], places=["", ""], source="x",
                  nodes={1: (0.0, 0.0, 0.0), 2: (1.0, 0.0, 0.0), 3: (2.0, 0.0, 0.0)})
    values.update(changes)
    return MeasuredModes(**values)


def test_uff55_round_trip_with_151_164_15(tmp_path):
    path = write_uff55(tmp_path / "m.uff", _modes())
    import pyuff

    assert list(pyuff.UFF(str(path)).get_set_types()) == [151, 164, 15, 55, 55]
    m = read_modes(path)
    assert is_modal_file(path)
    # E13.5 keeps 6 significant digits
    np.testing.assert_allclose(m.frequencies_hz, [100.0, 250.0], rtol=5e-6)
    np.testing.assert_allclose(m.damping, [0.01, 0.02], rtol=5e-6)
    np.testing.assert_allclose(m.shapes, SHAPES, rtol=5e-6)
    assert m.dofs == ["1:+z", "2:+z", "3:+x"] and m.places == ["dataset 4", "dataset 5"]
    assert m.nodes[2] == (1.0, 0.0, 0.0)


def test_complex_modes_reduced_to_real_by_the_stated_rule(tmp_path):
    # a real mode turned by any phase comes back (up to sign) with MPC 1
    shape = np.array([1.0, -2.0, 0.5])
    back, mpc = real_mode(shape * np.exp(1.1j))
    assert mpc == pytest.approx(1.0, abs=1e-12)
    assert abs(back @ shape) / (np.linalg.norm(back) * np.linalg.norm(shape)) == pytest.approx(1.0, abs=1e-12)
    # a shape with a 90 degree component: MPC = |Re|^2 / |phi|^2 along the principal axis (hand case)
    back, mpc = real_mode(np.array([2.0, 1j]))
    assert mpc == pytest.approx(4.0 / 5.0, rel=1e-12)
    m = read_modes(write_uff55(tmp_path / "c.uff", _modes(), complex_shapes=True))
    mac = (np.sum(m.shapes * SHAPES, axis=1) ** 2) / (np.sum(m.shapes ** 2, 1) * np.sum(SHAPES ** 2, 1))
    np.testing.assert_allclose(mac, 1.0, atol=1e-9)
    # f = |lambda| / 2 pi, zeta = -Re(lambda) / |lambda|
    np.testing.assert_allclose(m.frequencies_hz, [100.0, 250.0], rtol=5e-6)
    np.testing.assert_allclose(m.damping, [0.01, 0.02], rtol=1e-4)
    assert "complex mode reduced to real" in m.notes[0]


def test_csv_round_trip_and_recognition(tmp_path):
    path = write_csv(tmp_path / "m.csv", _modes())
    m = read_modes(path)
    np.testing.assert_array_equal(m.shapes, SHAPES)
    assert is_modal_file(path) and not is_modal_file("data/benchmark/measured.csv")
    assert not is_modal_file("data/benchmark/hammer.uff")


def _patch_analysis_type(path, dataset_line_offset, code):
    """Overwrite record 6 field 2 (analysis type) of the first dataset 55 in a written file."""
    lines = path.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "55")
    k = start + 6  # records 1-5 are the ID lines, then record 6
    lines[k] = lines[k][:10] + f"{code:10d}" + lines[k][20:]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("code, name", [(1, "static"), (6, "buckling")])
def test_dataset55_that_is_not_a_mode_is_refused(tmp_path, code, name):
    path = write_uff55(tmp_path / "s.uff", _modes())
    _patch_analysis_type(path, 0, code)
    with pytest.raises(MeasuredDataError, match=rf"dataset 4: dataset 55 of analysis type {code} \({name}\) is "
                                                "not a mode"):
        read_modes(path)


def test_non_finite_shape_is_refused_naming_the_place(tmp_path):
    path = write_csv(tmp_path / "n.csv", _modes())
    text = path.read_text().replace("3.0\n", "nan\n", 1)
    path.write_text(text)
    with pytest.raises(MeasuredDataError, match=r"line 4: mode 1: the shape is not finite at 3:\+x"):
        read_modes(path)
    uff = write_uff55(tmp_path / "n.uff", _modes())
    lines = uff.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if "3.00000e+00" in line)
    lines[k] = lines[k].replace("3.00000e+00", "        nan")
    uff.write_text("\n".join(lines) + "\n")
    with pytest.raises(MeasuredDataError, match="dataset 4 .*not finite at node"):
        read_modes(uff)


def test_test_node_not_in_the_model_is_refused():
    from tasks.modal_data import match_modes
    from tasks.problem import read_model_ref

    model, _ = read_model_ref("data/benchmark/model.toml")  # test nodes 1..6
    modes = _modes(dofs=["1:+z", "2:+z", "77:+z"], places=["dataset 4", "dataset 5"])
    with pytest.raises(MeasuredDataError, match=r"dataset 4: test node 77 \(77:\+z\) is not in the model"):
        match_modes(modes, model)
    matched = match_modes(_modes(dofs=["1:+z", "2:-z", "3:+z"]), model)
    assert matched.sensors == ["s1", "s2", "s3"]
    # the -z test DOF reads the model's +z sensor with the opposite sign
    col = matched.outputs.toarray()
    assert col[:, 1].min() == -1.0 and col[:, 0].max() == 1.0


def test_the_validator_describes_a_modal_file(tmp_path, capsys):
    from tasks.io.measured import main

    assert main([str(write_uff55(tmp_path / "m.uff", _modes()))]) == 0
    out = capsys.readouterr().out
    assert "2 modes at 3 test DOFs" in out and "mode 2: 250 Hz, damping ratio 0.02" in out
    path = write_uff55(tmp_path / "s.uff", _modes())
    _patch_analysis_type(path, 0, 6)
    assert main([str(path)]) == 2
    assert "analysis type 6 (buckling)" in capsys.readouterr().err


def test_modes_at_channels_named_as_sensors_match_by_name_and_round_trip_as_a_table(tmp_path):
    """A table's FRF channels are named as the model's sensors (the held-out cases' ``measured.csv``); modes
    identified from them carry those names, are written as a CSV table and matched to the sensors by name."""
    from tasks.modal_data import match_modes
    from tasks.problem import read_model_ref

    model, _ = read_model_ref("data/benchmark/model.toml")
    modes = _modes(dofs=["s3", "s1", "s2"])
    back = read_modes(write_csv(tmp_path / "named.csv", modes))
    assert back.dofs == ["s1", "s2", "s3"]  # names after test DOFs, in order
    np.testing.assert_array_equal(back.shapes, SHAPES[:, [1, 2, 0]])
    matched = match_modes(back, model)
    assert matched.sensors == ["s1", "s2", "s3"]
    # each column reads its sensor exactly as the model's own output row does
    np.testing.assert_array_equal(matched.outputs.toarray(), np.asarray(model.outputs[:, :3].todense()))
    with pytest.raises(MeasuredDataError, match=r"response 'nowhere' is neither a test DOF NODE:DIR nor a sensor"):
        match_modes(_modes(dofs=["s1", "s2", "nowhere"]), model)
    mixed = read_modes(write_csv(tmp_path / "mixed.csv", _modes(dofs=["s2", "1:+z", "3:+x"])))
    assert mixed.dofs == ["1:+z", "3:+x", "s2"]
