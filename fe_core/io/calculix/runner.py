"""Running CalculiX (``ccx``): an argument list, never a shell, in the run's own folder, with a time limit
and one thread; a failure quotes ccx's ``*ERROR`` lines (:class:`CcxError`), a missing executable says
how to install it (:class:`CcxMissing`), a run past its limit is :class:`CcxTimeout`."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CcxError", "CcxMissing", "CcxTimeout", "CcxRun", "ccx_executable", "run_ccx", "error_lines",
           "INSTALL_HINT"]

INSTALL_HINT = "install CalculiX with `apt-get install calculix-ccx` (Debian/Ubuntu) and make sure `ccx` is on PATH"


class CcxError(RuntimeError):
    """ccx failed: the message names the deck and quotes ccx's *ERROR lines."""


class CcxMissing(CcxError):
    """No ``ccx`` executable on PATH."""


class CcxTimeout(CcxError):
    """ccx ran past its time limit (the process was killed)."""


@dataclass
class CcxRun:
    folder: Path
    job: str
    seconds: float
    output: str


def ccx_executable() -> str:
    """The path of ``ccx`` (the environment variable ``CCX`` may name another executable)."""
    name = os.environ.get("CCX", "ccx")
    exe = shutil.which(name)
    if exe is None:
        raise CcxMissing(f"the CalculiX solver {name!r} is not installed or not on PATH: {INSTALL_HINT}")
    return exe


def error_lines(text: str, context: int = 2) -> list[str]:
    """ccx's ``*ERROR`` lines, each with up to ``context`` following non-blank lines (the card image)."""
    lines = text.splitlines()
    out = []
    for i, line in enumerate(lines):
        if "*ERROR" in line.upper():
            out.append(line.strip())
            out += [ln.strip() for ln in lines[i + 1:i + 1 + context] if ln.strip() and "*ERROR" not in ln.upper()]
    return out


def run_ccx(folder: str | Path, job: str, timeout: float, threads: int = 1,
            expect: tuple[str, ...] = ()) -> CcxRun:
    """Run ``ccx -i job`` in ``folder`` (holding ``job.inp``); its output goes to ``job.log``.

    Raises :class:`CcxError` quoting the *ERROR lines when ccx reports an error, exits non-zero or leaves
    out a file of ``expect`` (suffixes such as ``".sti"``), :class:`CcxTimeout` past ``timeout`` seconds.
    """
    folder = Path(folder)
    exe = ccx_executable()
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), CCX_NPROC_STIFFNESS=str(threads),
               CCX_NPROC_EQUATION_SOLVER=str(threads), CCX_NPROC_RESULTS=str(threads))
    deck = folder / f"{job}.inp"
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([exe, "-i", job], cwd=folder, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, timeout=timeout, env=env, shell=False)
    except subprocess.TimeoutExpired as exc:
        out = exc.output.decode(errors="replace") if isinstance(exc.output, bytes) else (exc.output or "")
        (folder / f"{job}.log").write_text(out)
        raise CcxTimeout(f"{deck}: ccx ran past its time limit of {timeout:g} s and was stopped "
                         "(raise solver_timeout in the model file if the deck needs longer)") from None
    seconds = time.perf_counter() - t0
    out = proc.stdout.decode(errors="replace")
    (folder / f"{job}.log").write_text(out)
    errors = error_lines(out)
    missing = [s for s in expect if not (folder / f"{job}{s}").exists()]
    if errors or proc.returncode != 0 or missing:
        quoted = "; ".join(errors) if errors else (out.strip().splitlines() or ["(no output)"])[-1]
        what = f"ccx rejected the deck (exit code {proc.returncode})" if errors or proc.returncode else \
            f"ccx wrote no {', '.join(missing)}"
        raise CcxError(f"{deck}: {what}: {quoted}")
    return CcxRun(folder, job, seconds, out)
