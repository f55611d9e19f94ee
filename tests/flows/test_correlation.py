"""The correlation analysis flow: FE samples in resumable Parquet chunks, Eq. 16, identifiability, page."""

from __future__ import annotations

import base64
import json
import re

import numpy as np
import pandas as pd
import pytest

from flows import correlation
from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ
from tasks import correlation as corr

FIGURES = ("correlation.png", "correlation_map.png", "singular_values.png")


@pytest.fixture(scope="module")
def harness(prefect_harness):
    """The session's Prefect test server (tests/flows/conftest.py)."""
    return prefect_harness


def small_meta(seed: int = 3) -> dict:
    return {"model": "three_plate", "frequencies_hz": MEASUREMENT_FREQUENCIES_HZ.tolist(), "seed": seed,
            "chunk_size": 10, "n_parameters": 6, "lower": -1.0, "upper": 1.0}


REFERENCES = {"alpha = 0": [0.0] * 6}


def test_correlation_flow_matches_numpy_resumes_and_writes_its_page(tmp_path, harness):
    folder = tmp_path / "corr"
    meta = small_meta()
    first = correlation.correlation_flow(str(folder), meta, 25, 1, REFERENCES)
    assert first["chunks_run"] == 3 and first["n_ok"] == 25 and first["failed"] == 0

    # Samples: uniform in the box, reproducible per chunk, the first 25 used.
    fe = pd.concat([pd.read_parquet(p) for p in sorted((folder / "fe").glob("chunk=*.parquet"))])
    X = fe.groupby("sample_id")[[f"alpha_{i}" for i in range(1, 7)]].first()
    np.testing.assert_array_equal(X.loc[10:19].to_numpy(), corr.chunk_samples(3, 1, 10, 6, -1.0, 1.0))
    assert X.to_numpy().min() > -1.0 and X.to_numpy().max() < 1.0

    # Eq. 16 against numpy.corrcoef on the stored amplitudes.
    fe = fe[fe["sample_id"] < 25].assign(amplitude=lambda d: np.hypot(d["real"], d["imag"]))
    wide = fe.pivot_table(index="sample_id", columns=["frequency_hz", "sensor"], values="amplitude")
    reference = np.corrcoef(X.loc[wide.index].to_numpy().T, wide.to_numpy().T)[:6, 6:]
    table = pd.read_parquet(folder / "correlation.parquet")
    assert len(table) == 6 * 72 and set(table["n_samples"]) == {25}
    got = table.pivot_table(index="parameter", columns=["frequency_hz", "sensor"], values="rho")
    np.testing.assert_allclose(got.loc[[f"alpha_{i}" for i in range(1, 7)], wide.columns].to_numpy(), reference,
                               atol=1e-12)

    # The identifiability record and the page with every figure embedded.
    ident = json.loads((folder / "identifiability.json").read_text())
    assert len(ident["alpha = 0"]["singular_values"]) == 6 and ident["alpha = 0"]["verdict"]
    page = (folder / "correlation.html").read_text()
    embedded = {name: data for data, name in re.findall(r'src="data:image/png;base64,([^"]+)" alt="([^"]+)"', page)}
    for name in FIGURES:
        raw = (folder / name).read_bytes()
        assert raw[:8] == b"\x89PNG\r\n\x1a\n" and len(raw) > 5000
        assert base64.b64decode(embedded[name]) == raw and f'href="{name}"' in page

    # Again: nothing to run. One chunk lost: only it runs, and the result is the same.
    assert correlation.correlation_flow(str(folder), meta, 25, 1, REFERENCES)["chunks_run"] == 0
    (folder / "fe" / "chunk=000001.parquet").unlink()
    assert correlation.correlation_flow(str(folder), meta, 25, 1, REFERENCES)["chunks_run"] == 1
    pd.testing.assert_frame_equal(pd.read_parquet(folder / "correlation.parquet"), table)
    # More samples reuse the finished chunks.
    assert correlation.correlation_flow(str(folder), meta, 35, 1, REFERENCES)["chunks_run"] == 1


def test_a_folder_made_with_other_settings_is_refused_naming_the_file_and_key(tmp_path):
    corr.prepare_folder(tmp_path, small_meta(seed=3))
    corr.prepare_folder(tmp_path, small_meta(seed=3))  # same settings: fine
    with pytest.raises(corr.CorrelationError, match=r"meta\.json: key 'seed'"):
        corr.prepare_folder(tmp_path, small_meta(seed=4))


@pytest.mark.parametrize("args, needle", [(["--samples", "2"], "at least 3"),
                                          (["--samples", "10", "--n-jobs", "0"], "n-jobs")])
def test_bad_command_line_exits_2_and_says_why(args, needle, tmp_path, capsys):
    assert correlation.main([*args, "--runs-dir", str(tmp_path)]) == 2
    assert needle in capsys.readouterr().err
