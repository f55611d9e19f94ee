"""The core stays plain numpy/scipy and exposes its public API."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import mrgp_core

FORBIDDEN = ("prefect", "pandas", "pyarrow", "joblib", "sklearn")
PACKAGE = Path(mrgp_core.__file__).resolve().parent


def test_importing_every_module_pulls_in_no_orchestration_or_io_library():
    code = (
        "import importlib, json, pkgutil, sys, mrgp_core\n"
        "for m in pkgutil.walk_packages(mrgp_core.__path__, 'mrgp_core.'):\n"
        "    importlib.import_module(m.name)\n"
        f"print(json.dumps(sorted(n for n in sys.modules if n.split('.')[0] in {FORBIDDEN!r})))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=PACKAGE.parent)
    assert json.loads(out.stdout) == []


def test_no_source_file_imports_a_forbidden_library_even_lazily():
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            offenders += [f"{path.name}: {n}" for n in names if n.split(".")[0] in FORBIDDEN]
    assert offenders == []


def test_public_api_is_exported():
    for name in ("fit", "condition", "MRGP", "Hyperparameters", "predicted_overall_error", "get_trainer",
                 "TRAINERS", "ProfileLikelihood", "regularise_q"):
        assert name in mrgp_core.__all__ and hasattr(mrgp_core, name)
    assert set(mrgp_core.TRAINERS) == {"gradient", "sao", "pso"}
