"""Route B: ccx as a black box, for parameters not linear in K or M (shell thicknesses, section sizes).

Each FE run writes the deck with its numbers scaled by ``1 + theta_k`` into its own folder, runs ccx
(``*FREQUENCY, STORAGE=YES`` with ``n_modes`` modes, then one ``*STEADY STATE DYNAMICS`` step per
frequency with ``*MODAL DAMPING, RAYLEIGH``) with a time limit, and reads the complex FRF at the sensors
from ``.dat``. ccx's FRF is a modal superposition: the modes above the ``n_modes``-th are left out (no
residual correction), which costs accuracy off resonance; ``n_modes`` well above the measured band keeps
it below the noise (0.2 % at 20 of 147 modes in ``tests/fe_core/test_calculix_deck.py``).

A folder whose ``done.json`` names the SHA-256 of its deck and whose ``.dat`` exists is complete and is
read again instead of run (resume); anything else is run again. A failed or timed-out run is a
:class:`FailedRun` quoting ccx's *ERROR lines, and the search goes on without it.

:func:`fd_gauss_newton` is the local search without solver Jacobians: each iteration one parallel round of
m + 1 runs (the point and forward differences), then step-halving trials of one run each.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...threads import cores, thread_map
from .deck import Deck, NumberRef
from .results import read_steady_state
from .runner import CcxError, run_ccx

__all__ = ["DeckFRF", "FailedRun", "fd_gauss_newton", "FDResult", "run_steady_state", "run_in_folder"]


@dataclass
class FailedRun:
    """A failed FE run: its folder and the solver's message (with its *ERROR lines)."""

    folder: Path
    theta: np.ndarray
    message: str


@dataclass
class DeckFRF:
    """The FRF of a deck at factors ``theta`` on some of its numbers (one ccx run per evaluation)."""

    deck: Deck
    numbers: list[NumberRef]
    sensors: list[tuple[int, int]]          # (deck node, component 0..2)
    excitation: tuple[int, int]
    damping: tuple[float, float]
    freqs_hz: np.ndarray
    n_modes: int = 40
    timeout: float = 600.0
    nominal: list[float] = field(init=False)

    def __post_init__(self):
        self.nominal = [self.deck.number(r) for r in self.numbers]   # a reference naming no number fails here
        self.freqs_hz = np.asarray(self.freqs_hz, float)

    def text(self, theta) -> str:
        node, comp = self.excitation
        a, b = self.damping
        nodes = sorted({n for n, _ in self.sensors})
        steps = [f"*NSET, NSET=FE_UPDATE_SENSORS\n{', '.join(map(str, nodes))}",
                 f"*STEP\n*FREQUENCY, STORAGE=YES\n{self.n_modes}\n*CLOAD\n{node}, {comp + 1}, 0.\n*END STEP"]
        for f in map(float, self.freqs_hz):
            steps.append(f"*STEP\n*STEADY STATE DYNAMICS\n{f!r}, {f!r}, 1, 1.\n*MODAL DAMPING, RAYLEIGH\n"
                         f",,{a!r},{b!r}\n*CLOAD\n{node}, {comp + 1}, 1.\n*NODE PRINT, NSET=FE_UPDATE_SENSORS\n"
                         "U\n*END STEP")
        numbers = {r: v * (1.0 + float(t)) for r, v, t in zip(self.numbers, self.nominal, theta)}
        return self.deck.text(numbers=numbers, steps="\n".join(steps) + "\n")

    def run(self, theta, folder: str | Path) -> np.ndarray:
        """The complex FRF, shape (p, n); reuses a complete folder. Raises CcxError on a failed run."""
        disp = run_steady_state(self.text(theta), folder, self.timeout, self.freqs_hz)
        return np.column_stack([disp[n][:, c] for n, c in self.sensors])


def _complete(folder: Path, sha: str) -> bool:
    done = folder / "done.json"
    try:
        return (done.exists() and (folder / "deck.dat").exists()
                and json.loads(done.read_text()).get("deck_sha256") == sha)
    except ValueError:            # a done.json cut short: not complete
        return False


def run_in_folder(text: str, folder: str | Path, timeout: float, check=None):
    """Run the deck ``text`` in ``folder`` (``deck.inp``, ccx's ``deck.dat``) unless the folder is complete: its
    ``done.json`` names the deck's SHA-256 and ``deck.dat`` exists. ``check(folder)`` reads the output (raising
    on a bad one) before ``done.json`` is written, last and atomically; returns its value. The folder is locked
    while it runs (two processes asking for the same deck wait for one another). Raises CcxError."""
    import fcntl

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    sha = hashlib.sha256(text.encode()).hexdigest()
    with open(folder / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        complete = _complete(folder, sha)
        if not complete:
            (folder / "done.json").unlink(missing_ok=True)
            (folder / "deck.inp").write_text(text)
            run_ccx(folder, "deck", timeout, expect=(".dat",))
        value = check(folder) if check is not None else None
        if not complete:
            tmp = folder / f".done.{os.getpid()}"
            tmp.write_text(json.dumps({"deck_sha256": sha}))
            os.replace(tmp, folder / "done.json")
    return value


def run_steady_state(text: str, folder: str | Path, timeout: float, freqs_hz) -> dict:
    """``{node: (p, 3) complex}``: the steady-state output at ``freqs_hz`` of the deck ``text`` run in
    ``folder`` (:func:`run_in_folder`: a complete folder is read, not run). Raises CcxError."""
    freqs_hz = np.asarray(freqs_hz, float)

    def read(folder):
        freqs, disp = read_steady_state(folder / "deck.dat")
        if freqs.size != freqs_hz.size or np.max(np.abs(freqs - freqs_hz) / freqs_hz) > 1e-6:
            raise CcxError(f"{folder / 'deck.dat'}: {freqs.size} frequencies, expected {freqs_hz.size}")
        return disp

    return run_in_folder(text, folder, timeout, read)


@dataclass
class FDResult:
    theta: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    fe_runs: int
    rounds: int
    failures: list


def fd_gauss_newton(model: DeckFRF, measured_amplitude, theta0, lower, upper, workdir: str | Path,
                    step: float = 1e-3, max_iterations: int = 10, tolerance: float = 1e-4,
                    workers: int | None = None) -> FDResult:
    """Gauss-Newton on the log-amplitude residual with forward-difference Jacobians (one parallel round of
    m + 1 ccx runs per iteration), steps clipped to ``[lower, upper]`` and halved while they do not lower
    the residual. Run k goes into ``workdir/run-<k>``."""
    log_u = np.log(np.asarray(measured_amplitude, float)).ravel()
    lo, hi = np.broadcast_to(lower, len(theta0)).astype(float), np.broadcast_to(upper, len(theta0)).astype(float)
    workdir = Path(workdir)
    count = {"runs": 0, "rounds": 0}
    failures: list[FailedRun] = []

    def batch(points):
        count["rounds"] += 1
        start = count["runs"]
        count["runs"] += len(points)

        def one(k):
            folder = workdir / f"run-{start + k}"
            try:
                return np.log(np.abs(model.run(points[k], folder))).ravel() - log_u
            except CcxError as exc:
                failures.append(FailedRun(folder, np.asarray(points[k]), str(exc)))
                return None

        return thread_map(one, range(len(points)), threads=workers or cores(-1))  # one ccx process per thread

    theta = np.clip(np.asarray(theta0, float), lo, hi)
    m = theta.size
    for _ in range(max_iterations):
        h = np.where(theta + step <= hi, step, -step)
        points = [theta] + [theta + h[i] * np.eye(m)[i] for i in range(m)]
        out = batch(points)
        if out[0] is None:
            raise CcxError(f"the FE run at {theta.tolist()} failed: {failures[-1].message}")
        r = out[0]
        if any(o is None for o in out[1:]):
            raise CcxError(f"a finite-difference run near {theta.tolist()} failed: {failures[-1].message}")
        J = np.column_stack([(out[i + 1] - r) / h[i] for i in range(m)])
        delta = np.linalg.lstsq(J, -r, rcond=None)[0]
        if np.max(np.abs(delta)) < tolerance:
            return FDResult(theta, r, J, count["runs"], count["rounds"], failures)
        for _ in range(8):
            trial = np.clip(theta + delta, lo, hi)
            rt = batch([trial])[0]
            if rt is not None and rt @ rt < r @ r:
                theta = trial
                break
            delta = delta / 2
        else:
            break
    out = batch([theta] + [theta + step * np.eye(m)[i] for i in range(m)])
    J = np.column_stack([(out[i + 1] - out[0]) / step for i in range(m)])
    return FDResult(theta, out[0], J, count["runs"], count["rounds"], failures)
