"""The model cache (fe_core.io.cache through tasks.problem.read_model_ref): a cached model is the model, and a
changed model file, mesh or segment under the same path is never served from the cache.

The references are fresh reads of the model files (fe_core.io.read_model, no cache). The bracket's coarse mesh
(8,388 DOFs) stands in for a large model (the size threshold is lowered); the changed mesh is the same geometry
meshed again by gmsh at another element size, written over the original file.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import tasks.problem as problem
from fe_core.io import cache, read_model

REPO = Path(__file__).resolve().parents[2]
BRACKET = REPO / "data" / "examples" / "bracket"


@pytest.fixture
def bracket(tmp_path, monkeypatch):
    """The coarse bracket's model file and mesh, copied where the test may change them; every model cached."""
    shutil.copy(BRACKET / "model_coarse.toml", tmp_path / "model.toml")
    shutil.copy(BRACKET / "bracket_coarse.msh", tmp_path / "bracket_coarse.msh")
    monkeypatch.setattr(problem, "CACHE_MIN_DOFS", 0)
    monkeypatch.delenv(problem.MODEL_CACHE_ENV, raising=False)
    monkeypatch.setattr(problem, "_MODELS", {})
    return tmp_path / "model.toml", tmp_path / "cache"


def read(path: Path, root: Path):
    """A new process's read: nothing remembered in memory."""
    problem._MODELS.clear()
    return problem.read_model_ref(str(path), root)


def assert_same_model(a, b):
    """Every array the FE runs read, equal to the last bit."""
    rng = np.random.default_rng(4)
    theta = rng.uniform(-0.5, 0.5, a.n_parameters)
    for x, y in [(a.stiffness(theta), b.stiffness(theta)), (a.mass(), b.mass())]:
        assert x.shape == y.shape
        assert np.array_equal(x.indptr, y.indptr) and np.array_equal(x.indices, y.indices)
        assert np.array_equal(x.data, y.data)
    for i in range(a.n_segments):
        assert (a.stiffness_segments.own(i) != b.stiffness_segments.own(i)).nnz == 0
    assert (a.outputs != b.outputs).nnz == 0
    assert np.array_equal(a.excitation_loads, b.excitation_loads)
    assert np.array_equal(a.free_dofs, b.free_dofs)
    assert a.segment_masses == b.segment_masses and a.sensor_names == b.sensor_names
    assert np.array_equal(a.cell_stiffness(np.arange(5)), b.cell_stiffness(np.arange(5)))


def test_cached_model_equals_the_file_and_is_served_without_assembly(bracket, monkeypatch):
    path, root = bracket
    first, ref = read(path, root)
    assert ref.cache and Path(ref.cache).parent == root  # written on the first read
    fresh = read_model(path)
    assert_same_model(first, fresh)
    # The second read maps the entry: no assembly at all.
    monkeypatch.setattr("fe_core.io.read_model", lambda *a, **k: pytest.fail("assembled, not served from the cache"))
    second, ref2 = read(path, root)
    assert ref2.cache == ref.cache
    assert_same_model(second, fresh)
    freqs = [310.0, 1300.0, 2400.0]
    theta = np.full(fresh.n_parameters, 0.1)
    assert np.array_equal(second.parameter_frf(theta, freqs), fresh.parameter_frf(theta, freqs))
    # An FE worker given the reference maps the same entry.
    problem._MODELS.clear()
    assert_same_model(problem.worker_model(ref2), fresh)


def test_changed_segment_under_the_same_path_is_not_served_from_the_cache(bracket):
    path, root = bracket
    before, ref = read(path, root)
    text = path.read_text()
    assert 'set = "rib_left"' in text and 'set = "rib_right"' in text
    path.write_text(text.replace('set = "rib_left"', 'set = "@@"').replace('set = "rib_right"', 'set = "rib_left"')
                    .replace('set = "@@"', 'set = "rib_right"'))  # the two ribs' segments swapped
    after, ref2 = read(path, root)
    assert ref2.checksum != ref.checksum and ref2.cache != ref.cache
    fresh = read_model(path)
    assert_same_model(after, fresh)
    assert (before.stiffness_segments.own(4) != after.stiffness_segments.own(4)).nnz > 0


def test_changed_mesh_under_the_same_path_is_not_served_from_the_cache(bracket):
    path, root = bracket
    before, ref = read(path, root)
    subprocess.run([sys.executable, str(BRACKET / "make_mesh.py"), "--size", "0.017", "--out",
                    str(path.parent / "bracket_coarse.msh")], check=True, capture_output=True)
    after, ref2 = read(path, root)
    assert ref2.checksum != ref.checksum and ref2.cache != ref.cache
    fresh = read_model(path)
    assert fresh.n_dofs != before.n_dofs
    assert_same_model(after, fresh)
    # Both entries stay until pruned; the stale one is never looked up again.
    assert cache.lookup(root, ref.checksum) is not None and cache.lookup(root, ref2.checksum) is not None


def test_entry_of_other_code_is_not_found(bracket, monkeypatch):
    path, root = bracket
    _, ref = read(path, root)
    monkeypatch.setattr(cache, "_DIGEST", "another version of fe_core")
    assert cache.lookup(root, ref.checksum) is None
    with pytest.raises(ValueError, match="another format or code"):
        cache.load(ref.cache)


def test_prune_keeps_the_most_recently_used(tmp_path):
    for k in range(cache.KEEP + 2):
        folder = cache.save({"k": np.arange(k + 1)}, tmp_path, f"checksum-{k}")
        mtime = 1_000_000 + k
        import os

        os.utime(folder / "index.json", (mtime, mtime))
    cache.load(tmp_path / cache.cache_key("checksum-0"))  # used now: the newest
    removed = cache.prune(tmp_path)
    kept = {p.name for p in tmp_path.iterdir()}
    assert len(removed) == 2 and cache.cache_key("checksum-0") in kept
    assert cache.cache_key("checksum-1") not in kept and cache.cache_key("checksum-2") not in kept
