"""The documentation's commands and paths are real: README.md and docs/**/*.md (guide/ and results/).

Every ``python -m <module> [subcommand]`` shown in them is run once with ``--help`` (deduplicated, all
in one child process, so the imports are paid once), and every long option a shown command uses must be
one that module's help lists. Every repository path they name (``fe_core/...``, ``data/...``,
``docs/...``, markdown links, ...) must exist. A wrong path, an unknown module or an unknown option fails.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]

#: Top-level folders and files of the repository a path in the docs may start with.
TOP = ("fe_core", "mrgp_core", "tasks", "flows", "benchmarks", "data", "docs", "tests", ".ci")
TOP_FILES = ("README.md", "pyproject.toml")
#: Paths the documented commands write, not files of the repository.
GENERATED = ("runs/", "out/")

COMMAND = re.compile(r"python3? -m ([A-Za-z_][\w.]*)((?:[ \t]+[^\s`|;&#\\]+|[ \t]*\\\n)*)")
#: Not after ":": `git show <commit>:docs/x.md` names a path in the history, not in this tree.
PATH = re.compile(r"(?<![\w./\-~$<:])((?:%s)/[\w./\-=*]*|(?:%s))" % ("|".join(re.escape(t) for t in TOP),
                                                                     "|".join(re.escape(t) for t in TOP_FILES)))
LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")
#: Modules the docs may show that are not this project's (their options are not checked).
FOREIGN = {"venv", "pip", "pytest", "http.server"}


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def commands(text: str) -> list[tuple[str, str | None, list[str]]]:
    """(module, subcommand or None, long options) of every ``python -m`` command in ``text``."""
    found = []
    for match in COMMAND.finditer(text):
        module, rest = match.group(1).rstrip("."), match.group(2).replace("\\\n", " ")
        words = rest.split()
        words = words[:words.index("--")] if "--" in words else words   # after a bare --: the wrapped command's
        sub = words[0] if words and re.fullmatch(r"[a-z][a-z_-]*", words[0]) else None   # rerun, make, stages
        options = [w.split("=", 1)[0] for w in words if re.fullmatch(r"--[a-z][\w-]*(=.*)?", w)]
        found.append((module, sub, options))
    return found


def repo_paths(path: Path, text: str) -> list[str]:
    """Repository paths named in ``text`` (relative to the root), and markdown links resolved from ``path``."""
    names = []
    for match in PATH.finditer(text):
        name = match.group(1).rstrip(".,:;)")
        after = text[match.end():match.end() + 1]
        if after == "<" or name.startswith(GENERATED):
            continue                                   # a placeholder (runs/<id>/...) or a run's output
        names.append(name + ("*" if after == "{" else ""))   # clean-seed{0..4}.csv: a glob
    for match in LINK.finditer(text):
        target = match.group(1)
        if re.match(r"[a-z]+:", target):
            continue                                   # http:, mailto:
        names.append(str((path.parent / target).resolve().relative_to(ROOT)))
    return names


def _out_args(text: str) -> set[str]:
    """The values of ``--out`` / ``--out-dir`` in commands: prefixes of files the command writes."""
    return {m.group(1) for m in re.finditer(r"--out(?:-dir)?[\s=]+([\w./-]+)", text)}


def _exists(name: str) -> bool:
    if any(ch in name for ch in "*"):
        return any(ROOT.glob(name))
    return (ROOT / name).exists()


def test_every_named_path_exists():
    missing = []
    for doc in DOCS:
        text = _text(doc)
        outs = _out_args(text)
        for name in repo_paths(doc, text):
            if name in outs or _exists(name):
                continue
            missing.append(f"{doc.relative_to(ROOT)}: {name}")
    assert not missing, "paths named in the docs that the repository lacks:\n" + "\n".join(sorted(set(missing)))


DOTTED = re.compile(r"`((?:fe_core|mrgp_core|tasks|flows|benchmarks)(?:\.[A-Za-z_]\w*)+)`")


def resolve(dotted: str) -> bool:
    """Whether ``dotted`` is an importable module, or an attribute (chain) of one."""
    import importlib

    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        try:
            for attr in parts[cut:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return False
        return True
    return False


def test_every_named_module_and_attribute_exists():
    """`fe_core.solvers.frf.BlockKrylov` and the like, in backticks: the module imports and has the name."""
    missing = sorted({f"{doc.relative_to(ROOT)}: {m.group(1)}" for doc in DOCS
                      for m in DOTTED.finditer(_text(doc)) if not resolve(m.group(1))})
    assert not missing, "dotted names in the docs that do not resolve:\n" + "\n".join(missing)


HELP_CHILD = r"""
import contextlib, importlib.util, io, json, runpy, sys
out = {}
for key in json.loads(sys.argv[1]):
    module, _, sub = key.partition(" ")
    try:
        spec = importlib.util.find_spec(module)
        if spec is None:
            raise ImportError("not found")
        origin = spec.origin if spec and not spec.submodule_search_locations else \
            (spec.submodule_search_locations[0] + "/__main__.py" if spec else None)
        source = open(origin, encoding="utf-8").read()
    except (ImportError, OSError, TypeError) as exc:
        out[key] = [f"no such module: {exc}", ""]
        continue
    if "ArgumentParser" not in source and "parse_no_options" not in source:
        out[key] = ["no command-line parser: --help would run the command itself", ""]
        continue                                    # never run a command for real from a test
    sys.argv = [module] + ([sub] if sub else []) + ["--help"]
    buf = io.StringIO()
    code = None
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            runpy.run_module(module, run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        code = exc.code
    except BaseException as exc:
        code = f"{type(exc).__name__}: {exc}"
    out[key] = [code, buf.getvalue()]
print("HELP-JSON" + json.dumps(out))
"""


def _helps(keys: list[str]) -> dict[str, tuple[object, str]]:
    proc = subprocess.run([sys.executable, "-c", HELP_CHILD, json.dumps(keys)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300, env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("HELP-JSON")]
    assert line, f"the --help child died: {proc.stderr[-2000:]}"
    return {k: (v[0], v[1]) for k, v in json.loads(line[-1][len("HELP-JSON"):]).items()}


def all_commands() -> dict[str, set[str]]:
    """{"module[ sub]": long options used with it} over README.md and docs/**/*.md."""
    used: dict[str, set[str]] = {}
    for doc in DOCS:
        for module, sub, options in commands(_text(doc)):
            if module in FOREIGN:
                continue
            used.setdefault(module + (f" {sub}" if sub else ""), set()).update(options)
    return used


def test_every_shown_command_parses():
    used = all_commands()
    assert "flows.update" in used and "flows.report" in used
    helps = _helps(sorted(used))
    bad = []
    for key, options in sorted(used.items()):
        code, text = helps[key]
        if code not in (0, None) or "usage:" not in text:
            bad.append(f"python -m {key} --help: exit {code!r}: {text.strip()[-300:]}")
            continue
        unknown = sorted(o for o in options if not re.search(re.escape(o) + r"(?![\w-])", text))
        if unknown:
            bad.append(f"python -m {key}: options its --help does not list: {', '.join(unknown)}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("text, expected", [
    ("python -m flows.update rerun --run-id a --stage train", [("flows.update", "rerun", ["--run-id", "--stage"])]),
    ("python -m flows.update --model data/x.toml \\\n    --measured y.csv", [("flows.update", None,
                                                                          ["--model", "--measured"])]),
    ("python -m benchmarks.scaling update --model m.toml -- --n-jobs 1", [("benchmarks.scaling", "update",
                                                                          ["--model"])]),
])
def test_command_extraction(text, expected):
    assert commands(text) == expected


def test_a_wrong_path_or_module_is_caught(tmp_path):
    """The checks above can fail: a missing path is reported, an unknown module's --help does not exit 0."""
    doc = ROOT / "docs" / "guide" / "x.md"
    names = repo_paths(doc, "see `fe_core/no_such_file.py` and [this](no-such-page.md)")
    assert names == ["fe_core/no_such_file.py", "docs/guide/no-such-page.md"]
    assert not any(_exists(n) for n in names)
    assert repo_paths(doc, "the last version: `git show 0cbca1f:docs/gone.md`") == []
    assert resolve("fe_core.solvers.frf.BlockKrylov") and not resolve("fe_core.solvers.frf.NoSuchThing")
    assert not resolve("fe_core.no_such_module")
    helps = _helps(["flows.no_such_module", "flows.report"])
    assert helps["flows.no_such_module"][0] not in (0, None)
    assert helps["flows.report"][0] == 0 and "--run-id" in helps["flows.report"][1]
    assert "--no-such-option" not in helps["flows.report"][1]          # an unknown option would be reported


# -- the README's headline results are the ones docs/results/headline.md measured -----------------------------
HEADLINE = ROOT / "docs" / "results" / "headline.md"
NUMBER = re.compile(r"\d+(?:[.,]\d+)*(?:e-?\d+)?")
#: How far behind HEAD the commit a headline page ran on may be, in commits that can change a figure: those that
#: change the code or the data (:data:`BEHAVIOUR_PATHS`; merges count through the commits they bring). A commit
#: of docs or tests changes no figure. (Issue 39: rerun before a stop that changes behaviour.)
MAX_BEHIND = 40
BEHAVIOUR_PATHS = ("fe_core", "mrgp_core", "strategies", "tasks", "flows", "benchmarks", "data", "pyproject.toml")


def headline_results(readme: str) -> list[str]:
    """The result column (the second) of the table under ``## Headline results``."""
    section = readme.partition("## Headline results")[2]
    table = []
    for line in section.splitlines():
        if line.startswith("|"):
            table.append(line)
        elif table:
            break
    cells = [[c.strip() for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))] for line in table[2:]]
    return [row[1] for row in cells if len(row) >= 2]


def missing_figures(readme: str, page: str) -> list[str]:
    """Numbers of the README's headline result column that the page does not show (as whole numbers: 18 is
    not found in 180)."""
    shown = set(NUMBER.findall(page))
    return [f"{number!r} of {cell!r}" for cell in headline_results(readme) for number in NUMBER.findall(cell)
            if number not in shown]


def test_every_headline_figure_is_on_the_headline_page():
    results = headline_results(_text(ROOT / "README.md"))
    assert len(results) >= 10, "the README's headline table was not found"
    missing = missing_figures(_text(ROOT / "README.md"), _text(HEADLINE))
    assert not missing, ("figures of the README's headline table that docs/results/headline.md does not show "
                         "(rerun `python -m benchmarks.headline`):\n" + "\n".join(missing))


def test_a_figure_missing_from_the_page_is_caught():
    readme = "## Headline results\n\n| what | result | details |\n|---|---|---|\n| a | 18 FE runs, 0.0005 | x |\n"
    assert missing_figures(readme, "18 FE runs and 0.0005") == []
    assert missing_figures(readme, "19 FE runs, 0.0005") == ["'18' of '18 FE runs, 0.0005'"]
    assert missing_figures(readme, "180 FE runs, 0.00051") == ["'18' of '18 FE runs, 0.0005'",
                                                               "'0.0005' of '18 FE runs, 0.0005'"]


def test_the_headline_page_is_recent():
    """Every commit the page names ran at most MAX_BEHIND commits that change code or data before HEAD (skipped
    without git)."""
    import shutil

    if shutil.which("git") is None or subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT,
                                                     capture_output=True).returncode != 0:
        pytest.skip("git (or the repository's history) is not available")
    line = next(ln for ln in _text(HEADLINE).splitlines() if ln.startswith("Written by"))
    commits = re.findall(r"`([0-9a-f]{7,40})`", line)
    assert commits, "docs/results/headline.md names no commit it ran on"
    for commit in commits:
        count = subprocess.run(["git", "rev-list", "--no-merges", "--count", f"{commit}..HEAD", "--",
                                *BEHAVIOUR_PATHS], cwd=ROOT, capture_output=True, text=True)
        assert count.returncode == 0, f"docs/results/headline.md ran on {commit}, which is not in this history"
        behind = int(count.stdout)
        assert behind <= MAX_BEHIND, (f"docs/results/headline.md ran on {commit}, {behind} commits of code or data "
                                      f"behind HEAD (at most {MAX_BEHIND}): rerun `python -m benchmarks.headline`")
