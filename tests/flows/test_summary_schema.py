"""The summary's schema (tasks/io/summary.schema.json): its version, its documentation, and older records read in it.

Real summaries of every kind are validated where the tests make them (the check_summary fixture of
tests/flows/conftest.py): an FRF run with and without intervals, repeats and the hybrid in
tests/flows/test_report.py (with broken ones refused), test_update.py, test_intervals_stage.py, a modal run in
test_modal_update.py, test_modal_resume.py (with its closure) and test_modal_identify.py, a CalculiX deck in
test_calculix_route_b.py.
"""

from __future__ import annotations

import json
import re

from flows.config import REPO
from tasks.io.summary import KINDS, SCHEMA_PATH, SCHEMA_VERSION, read_summary, upgrade

SCHEMA = json.loads(SCHEMA_PATH.read_text())


def test_the_schema_is_draft_2020_12_of_this_version_and_kinds():
    import jsonschema

    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    assert SCHEMA["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert SCHEMA["properties"]["schema_version"] == {"const": SCHEMA_VERSION}
    assert tuple(SCHEMA["properties"]["kind"]["enum"]) == KINDS
    assert {c["if"]["properties"]["kind"]["const"] for c in SCHEMA["allOf"]} == set(KINDS)
    assert SCHEMA["unevaluatedProperties"] is False  # a field the schema does not know is refused


def test_the_guide_names_every_field_of_the_schema():
    """docs/guide/runs.md, "The summary": every top-level field of every kind is described there."""
    text = (REPO / "docs" / "guide" / "runs.md").read_text()
    section = text[text.index("## The summary"):]
    section = section[:section.index("\n## ", 1)]
    named = set(re.findall(r"`([a-z_0-9]+)`", section))
    fields = set(SCHEMA["properties"]) | {f for kind in KINDS for f in SCHEMA["$defs"][kind]["properties"]}
    assert fields - named == set()


def test_a_record_from_before_the_schema_is_read_in_its_shape(tmp_path):
    frf = {"parameters": {"alpha_1": 0.1, "alpha_2": -0.2}, "intervals": {"alpha_1": [0.0, 0.2], "alpha_2": [None, None]},
           "interval_details": {"std": {"alpha_1": 0.05, "alpha_2": None}}, "fe_evaluations": 9, "converged": True}
    s = upgrade(frf)
    assert s["kind"] == "frf" and s["parameters"] == frf["parameters"]
    assert s["intervals"] == {"alpha_1": {"lower95": 0.0, "upper95": 0.2, "sd": 0.05},
                              "alpha_2": {"lower95": None, "upper95": None, "sd": None}}
    modal = {"kind": "modal update", "folder": "/x/m", "fe_runs": 12, "inside95": {"alpha_1": True},
             "parameters": {"alpha_1": {"value": -0.6, "sd": 0.004, "lower95": -0.608, "upper95": -0.592}}}
    s = upgrade(modal)
    assert s["kind"] == "modal" and s["parameters"] == {"alpha_1": -0.6} and s["run_folder"] == "/x/m"
    assert s["intervals"]["alpha_1"] == {"lower95": -0.608, "upper95": -0.592, "sd": 0.004}
    assert s["fe_evaluations"] == 12 and s["intervals_contain_truth"] == {"alpha_1": True}
    assert "folder" not in s and "inside95" not in s and "fe_runs" not in s
    repeats = {"parameters": {"alpha_1": 0.1}, "repeats": {"n": 1}, "runs": [frf]}
    s = upgrade(repeats)
    assert s["kind"] == "repeats" and s["runs"][0]["intervals"]["alpha_1"]["sd"] == 0.05
    (tmp_path / "summary.json").write_text(json.dumps(modal))
    assert read_summary(tmp_path)["parameters"] == {"alpha_1": -0.6}
    assert json.loads((tmp_path / "summary.json").read_text()) == modal  # read, never rewritten
    current = {"schema_version": SCHEMA_VERSION, "kind": "modal", "parameters": {"alpha_1": -0.6}}
    assert upgrade(current) is current

