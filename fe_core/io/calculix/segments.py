"""Route A: segment stiffness and mass matrices from ccx.

K and M are linear in each segment's Young's modulus and density. One ccx run of the deck as it is and
one per segment with that segment's modulus and density doubled (m + 1 runs of
``*FREQUENCY, SOLVER=MATRIXSTORAGE``, in parallel) give ``K_i = K^(i) - K^(0)``, ``M_i = M^(i) - M^(0)``
and the remainder ``K_0 = K^(0) - sum_i K_i`` (springs, cells in no segment). The segment's section gets
its own copy of its material, so a material shared with other sections stays as it is for them.

The matrices are kept in a cache keyed by the SHA-256 of the decks run (``$FE_CALCULIX_CACHE``, default
``~/.cache/fe-update/calculix``): a model is read in every worker process, ccx runs once.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ...threads import cores, thread_map
from .deck import Deck, NumberRef
from .results import read_storage
from .runner import ccx_executable, run_ccx

__all__ = ["Segment", "segment_matrices", "segment_decks", "cache_dir", "MATRIX_STEP", "CHOP_RTOL"]

MATRIX_STEP = "*STEP\n*FREQUENCY, SOLVER=MATRIXSTORAGE\n*END STEP\n"
#: Entries of a difference of stored matrices below this fraction of the largest entry are round-off
#: (ccx writes 14 significant digits).
CHOP_RTOL = 1e-11


@dataclass
class Segment:
    """A segment: its name, element set, section card and the numbers of its material."""

    name: str
    elset: str
    section: int
    modulus: NumberRef
    density: NumberRef | None


def cache_dir() -> Path:
    return Path(os.environ.get("FE_CALCULIX_CACHE", Path.home() / ".cache" / "fe-update" / "calculix"))


def _material_copy(deck: Deck, seg: Segment, name: str, factor: float) -> str:
    """A copy of the segment's material named ``name`` with its modulus and density times ``factor``."""
    mat = (deck.cards[seg.section].param("MATERIAL") or "").upper()
    out = [f"*MATERIAL, NAME={name}"]
    for at in deck.material_cards[mat].values():
        card = deck.cards[at]
        out.append(", ".join([card.keyword] + [k if v == "" else f"{k}={v}" for k, v in card.params.items()]))
        for r, (line, _, _) in enumerate(card.data):
            fields = line.split(",")
            if r == 0 and at in (seg.modulus.card, seg.density.card if seg.density else -1):
                fields[0] = repr(deck.number(NumberRef(at, 0, 0)) * factor)
            out.append(",".join(fields))
    return "\n".join(out)


def segment_decks(deck: Deck, segments: list[Segment], factor: float = 2.0) -> list[str]:
    """The m + 1 deck texts: the deck as it is, then one per segment with its modulus and density scaled."""
    texts = [deck.text(steps=MATRIX_STEP)]
    for i, seg in enumerate(segments):
        name = f"FE_UPDATE_SEGMENT_{i + 1}"
        texts.append(deck.text(params={seg.section: {"MATERIAL": name}},
                               extra=_material_copy(deck, seg, name, factor), steps=MATRIX_STEP))
    return texts


def _chop(A: sp.csr_matrix, scale: float) -> sp.csr_matrix:
    A = sp.csr_matrix(A)
    A.data[np.abs(A.data) <= CHOP_RTOL * scale] = 0.0
    A.eliminate_zeros()
    return A


def segment_matrices(deck: Deck, segments: list[Segment], timeout: float, workers: int | None = None,
                     factor: float = 2.0):
    """(K_segments, M_segments, K_0, M_0, labels) from m + 1 ccx runs (or the cache).

    Raises the runner's :class:`CcxError` (quoting ccx's *ERROR lines) when a run fails; its folder is kept
    and named in the message.
    """
    texts = segment_decks(deck, segments, factor)
    exe = ccx_executable()
    key = hashlib.sha256("\0".join([exe, str(factor)] + texts).encode()).hexdigest()[:32]
    root = cache_dir()
    cached = root / f"{key}.npz"
    if cached.exists():
        with np.load(cached, allow_pickle=False) as z:
            n = int(z["n"])
            labels = z["labels"]
            full = [sp.csr_matrix((z[f"d{k}"], z[f"i{k}"], z[f"p{k}"]), shape=(n, n)) for k in range(2 * len(texts))]
        Ks, Ms = full[0::2], full[1::2]
    else:
        root.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f"run-{key[:8]}-", dir=root))

        def one(k: int):
            folder = work / f"run{k}"
            folder.mkdir()
            (folder / "deck.inp").write_text(texts[k])
            run_ccx(folder, "deck", timeout, expect=(".sti", ".mas", ".dof"))
            return read_storage(folder, "deck")

        results = thread_map(one, range(len(texts)), threads=workers or cores(-1))  # one ccx process per thread
        labels = results[0][2]
        for k, r in enumerate(results[1:], start=1):
            if not np.array_equal(r[2], labels):
                raise ValueError(f"{deck.path}: ccx's DOF table differs between the base run and segment "
                                 f"{segments[k - 1].name!r}'s run ({work})")
        Ks, Ms = [r[0] for r in results], [r[1] for r in results]
        n = labels.shape[0]
        arrays = {"n": np.array(n), "labels": labels}
        for k, A in enumerate(x for pair in zip(Ks, Ms) for x in pair):
            arrays.update({f"d{k}": A.data, f"i{k}": A.indices, f"p{k}": A.indptr})
        tmp = root / f".{key}.{os.getpid()}.npz"
        np.savez(tmp, **arrays)
        os.replace(tmp, cached)
        shutil.rmtree(work, ignore_errors=True)
    K0, M0 = Ks[0], Ms[0]
    kscale, mscale = abs(K0).max(), abs(M0).max()
    Ki = [_chop((Ks[i + 1] - K0) / (factor - 1.0), kscale) for i in range(len(segments))]
    Mi = [_chop((Ms[i + 1] - M0) / (factor - 1.0), mscale) for i in range(len(segments))]
    K_rest = _chop(K0 - sum(Ki, sp.csr_matrix(K0.shape)), kscale)
    M_rest = _chop(M0 - sum(Mi, sp.csr_matrix(M0.shape)), mscale)
    return Ki, Mi, K_rest, M_rest, labels
