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
