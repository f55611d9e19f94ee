"""``data/update.example.toml`` documents every setting and loads as the defaults."""

from __future__ import annotations

import dataclasses
import re

from flows.config import REPO, UpdateConfig, load_config

EXAMPLE = REPO / "data" / "update.example.toml"


def test_every_key_is_in_the_example_file():
    text = EXAMPLE.read_text()
    keys = {f.name for f in dataclasses.fields(UpdateConfig)}
    written = set(re.findall(r"^#? ?([a-z_]+) = ", text, flags=re.MULTILINE))
    assert keys - written == set()


def test_the_example_file_is_the_defaults():
    assert load_config(EXAMPLE) == UpdateConfig()


def test_every_key_has_its_flag_and_help_and_reaches_the_strategies_options(tmp_path, capsys):
    """One config path: the flags and --help are made from the declared settings, and a value set in a TOML file
    (or by its flag) arrives in every strategy's options that use the key."""
    import pytest

    from flows import update
    from flows.config import KEYS
    from strategies import registry
    from strategies.hybrid import HybridOptions
    from strategies.paper import PaperOptions
    from strategies.polish import PolishOptions

    with pytest.raises(SystemExit):
        update.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    for key in KEYS:
        assert key.help and all(flag in text for flag in key.flags), key.name
        assert " ".join(key.help.split())[:40] in text, key.name
    cfg = tmp_path / "c.toml"
    cfg.write_text("s = 7\nw = 99\npolish_target = 0.001\nmax_fe_evaluations = 60\nnoise = 0.02\npolish_max_fe = 30\n")
    config = update.load_config(cfg, starts=3, trainer="sao")
    hybrid, = registry.get("hybrid").settings(config)
    assert hybrid == HybridOptions(target=0.001, noise=0.02, max_cost=60.0, space_filling=7, candidates=99, starts=3,
                                   trainer="sao")
    paper, polishing = registry.get("adaptive").settings(config)
    assert paper == PaperOptions(s=7, w=99, max_fe=60, trainer="sao")
    assert polishing == PolishOptions(target=0.001, max_evaluations=30)
