"""Settings declared once: dataclass fields that are also keys of the run's config, its TOML file and its flags.

A strategy's options are a frozen dataclass (``HybridOptions``, ``PaperOptions``, ``PolishOptions``); a field
that a user may set is marked with :func:`setting` (it *declares* a config key: its help text, its flag, its
choices) or with :func:`uses` (it takes the value of a key declared elsewhere: the hybrid's space-filling
round uses the paper loop's ``s``, every strategy's budget is the run's ``max_fe_evaluations``). Fields without
either keep their defaults (tuning constants measured in the docs). ``flows/config.py`` makes the run's
config (:class:`flows.config.UpdateConfig`), the TOML keys and the command line's flags from these fields,
and :func:`from_settings` makes a strategy's options from a config. Every key is declared exactly once.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field

__all__ = ["setting", "uses", "Key", "keys_of", "from_settings"]

_MISSING = dataclasses.MISSING


def setting(default=_MISSING, *, help: str, key: str | None = None, flag: str | None = None,
            choices: tuple | None = None, metavar: str | None = None, default_factory=_MISSING):
    """A field that declares a config key (``key``: default the field's name).

    ``help``: one sentence for ``--help`` and the docs; ``flag``: the command line's flag (default
    ``--<key with dashes>``; ``""``: none); ``choices``: the allowed values; ``metavar``: for ``--help``.
    """
    meta = {"setting": key, "declares": True, "help": help, "flag": flag, "choices": choices, "metavar": metavar}
    if default_factory is not _MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


def uses(key: str, default=_MISSING, *, default_factory=_MISSING):
    """A field that takes the value of the config key ``key``, declared by another field."""
    meta = {"setting": key, "declares": False}
    if default_factory is not _MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class Key:
    """One config key: its name, Python type, default, help, flag, choices; ``owner``: the class declaring it."""

    name: str
    type: object
    default: object
    help: str
    flag: str | None
    choices: tuple | None
    metavar: str | None
    owner: str

    @property
    def flags(self) -> list[str]:
        """The command-line flags (none for ``flag=""``); one letter keys take one dash (``-q``)."""
        if self.flag == "":
            return []
        if self.flag:
            return [self.flag]
        return [f"-{self.name}" if len(self.name) == 1 else f"--{self.name.replace('_', '-')}"]


def _default(f: dataclasses.Field):
    if f.default is not _MISSING:
        return f.default
    if f.default_factory is not _MISSING:
        return f.default_factory()
    return None


def keys_of(cls) -> tuple[list[Key], dict[str, str]]:
    """(the keys ``cls`` declares, {field: key} of every field bound to a key)."""
    hints = typing.get_type_hints(cls)
    declared, bound = [], {}
    for f in dataclasses.fields(cls):
        if "setting" not in f.metadata:
            continue
        key = f.metadata["setting"] or f.name
        bound[f.name] = key
        if f.metadata.get("declares"):
            declared.append(Key(key, hints[f.name], _default(f), f.metadata["help"], f.metadata.get("flag"),
                                f.metadata.get("choices"), f.metadata.get("metavar"), cls.__name__))
    return declared, bound


def from_settings(cls, config, **fixed):
    """An instance of ``cls`` from a config (attributes or a mapping named by key): every field bound to a key
    takes its value (converted to the field's type: an int budget to a float one), the others their defaults;
    ``fixed``: values of fields set by the strategy's entry (e.g. ``conventional=True``)."""
    _, bound = keys_of(cls)
    hints = typing.get_type_hints(cls)
    get = config.get if isinstance(config, Mapping) else (lambda k, d=None: getattr(config, k, d))
    values = {}
    for name, key in bound.items():
        value = get(key, None)
        if value is None and not _optional(hints[name]):
            continue
        if hints[name] is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        values[name] = value
    return cls(**{**values, **fixed})


def _optional(tp) -> bool:
    return type(None) in typing.get_args(tp)
