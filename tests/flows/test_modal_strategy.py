"""The modal update's --strategy: hybrid (local fits) or adaptive/paper (the paper's loop, tested in memory in
tests/strategies/test_modal_paper.py); a strategy the modal path does not offer exits 2 naming the key."""

from __future__ import annotations

from flows import update

MODEL = "data/examples/modal/model.toml"
MODES = "data/examples/modal/modes.uff"


def test_the_conventional_baseline_is_refused_for_modal_data(tmp_path, capsys):
    config = tmp_path / "c.toml"
    config.write_text('strategy = "conventional"\n')
    argv = ["--config", str(config), "--model", MODEL, "--measured", MODES, "--runs-dir", str(tmp_path / "runs"),
            "--run-id", "r"]
    assert update.main(argv) == 2
    err = capsys.readouterr().err
    assert "modes.uff: key 'strategy': 'conventional'" in err and "adaptive" in err, err
    assert not (tmp_path / "runs").exists()


def test_an_unknown_modal_strategy_is_refused(tmp_path, capsys):
    argv = ["--model", MODEL, "--measured", MODES, "--strategy", "annealing", "--runs-dir", str(tmp_path / "runs")]
    try:
        code = update.main(argv)
    except SystemExit as exc:  # argparse's refusal of a choice
        code = exc.code
    assert code == 2
    assert "annealing" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()
