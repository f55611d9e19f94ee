"""Raw hammer records of the three-plate benchmark: ``data/examples/hammer_records/hammer_records.uff``.

    python -m benchmarks.make.hammer_records        # about a minute

The test of ``benchmarks.make.hammer`` (a hammer at sensor s5's point along z, accelerometers at the six
sensors, the structure at ``fe_core.benchmark.ALPHA_ACTUAL``), recorded as an analyser does rather than
as averaged spectra: ``HITS`` hits, each a force record and six acceleration records of ``RECORD_S`` at
``SAMPLE_RATE_HZ``, written as UFF58 time records (function type 1; accelerations in g, the force in N).

The route is independent of the frequency-domain solvers the update uses: the time responses are the
**modal superposition** of all the model's modes (dense ``eigh`` of ``K(alpha), M``; Rayleigh damping
``a M + b K`` keeps the modes real, ``zeta_r = a / (2 omega_r) + b omega_r / 2``), each modal oscillator
stepped exactly for a force that is linear between samples (first-order hold, the 2 x 2 state matrix
exponential) on a grid ``OVERSAMPLE`` times finer than the records. The accelerations are
``q_r'' = u_r - 2 zeta_r omega_r q_r' - omega_r^2 q_r`` summed over the modes at each step. Force and
responses then pass the same anti-alias filter and decimation (``scipy.signal.resample_poly``), as in an
analyser, so the filter cancels in the FRF below the band.

Each hit: a half-sine pulse of ``PULSE_S`` (+-10 %) and ``PEAK_FORCE_N`` (+-30 %), starting
``PRETRIGGER_S`` after the record's start (plus up to one sample of trigger jitter). Noise:

- **force noise**: white, ``FORCE_NOISE`` of the peak force rms on the force record;
- **response noise**: an unmeasured random force (white, ``AMBIENT`` of the peak force rms) along z at the
  mesh node nearest ``AMBIENT_POINT`` (an edge of the plate between s3 and s4, away from every sensor),
  through the same modal model: ambient vibration that the hammer's force does not explain;
- **sensor floor**: white, ``FLOOR`` of each channel's largest |acceleration| rms.

The script prints how far the H1 of these records (read back by ``tasks.io.measured``) is from the
exact FRF (the modal sum at the lines, checked against the direct solve of ``ParametricModel.frf_channels``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "data" / "examples" / "hammer_records" / "hammer_records.uff"
MODEL = REPO / "data" / "benchmark" / "model.toml"
SEED = 40
HITS = 5
SAMPLE_RATE_HZ = 1024.0
RECORD_S = 1.0
OVERSAMPLE = 16
PULSE_S = 2e-3            # half-sine contact time: a medium tip, force spectrum -6 dB at 400 Hz
PEAK_FORCE_N = 200.0
PRETRIGGER_S = 0.02
FORCE_NOISE = 1e-3        # force channel noise, rms / peak force
AMBIENT = 1e-3            # unmeasured random force at s2, rms / peak force
FLOOR = 1e-3              # sensor floor, rms / the channel's largest |acceleration|
HAMMER_NODE = 5
AMBIENT_POINT = (0.30, -0.07, 0.01)  # m: where the ambient force acts (z): an edge, no sensor near


def modal_basis(K, M, damping):
    """Natural circular frequencies (m,), damping ratios (m,) and mass-normalised modes (n, m) of ``K, M``."""
    from scipy.linalg import eigh

    lam, phi = eigh(K, M)
    omega = np.sqrt(np.maximum(lam, 0.0))
    a, b = damping
    return omega, a / (2 * omega) + b * omega / 2, phi


def foh_steps(omega, zeta, dt):
    """Exact first-order-hold step of each modal oscillator ``q'' + 2 zeta omega q' + omega^2 q = u``.

    Returns ``Phi`` (m, 2, 2), ``G0`` (m, 2), ``Gr`` (m, 2): ``x_{k+1} = Phi x_k + G0 u_k + Gr (u_{k+1} - u_k)``
    with ``x = (q, q')`` (the augmented matrix exponential of a ramp input).
    """
    from scipy.linalg import expm

    m = omega.size
    A = np.zeros((m, 4, 4))
    A[:, 0, 1] = 1.0
    A[:, 1, 0] = -omega**2
    A[:, 1, 1] = -2 * zeta * omega
    A[:, 1, 2] = 1.0
    A[:, 2, 3] = 1.0 / dt
    E = expm(A * dt)
    return E[:, :2, :2], E[:, :2, 2], E[:, :2, 3]


def modal_accelerations(omega, zeta, outputs, inputs, forces, dt):
    """Accelerations at the outputs for forces at the inputs, by exact FOH steps of every mode.

    Parameters
    ----------
    omega, zeta : ndarray, shape (m,)
    outputs : ndarray, shape (c, m)
        Mode shapes at the output DOFs (mass-normalised).
    inputs : ndarray, shape (m, k)
        Mode shapes at the ``k`` input DOFs.
    forces : ndarray, shape (h, k, t), N
        The force at each input, sampled every ``dt`` (linear in between), for ``h`` independent runs.
    dt : float, s

    Returns
    -------
    ndarray, shape (h, c, t), m/s^2
    """
    Phi, G0, Gr = foh_steps(omega, zeta, dt)
    h, _, t = forces.shape
    m = omega.size
    x = np.zeros((h, m, 2))
    out = np.empty((h, outputs.shape[0], t))
    u = forces[:, :, 0] @ inputs.T  # modal forces (h, m) at step k, made one step at a time (all at once is GBs)
    for k in range(t):
        out[:, :, k] = (u - 2 * zeta * omega * x[..., 1] - omega**2 * x[..., 0]) @ outputs.T
        if k + 1 < t:
            u_next = forces[:, :, k + 1] @ inputs.T
            x = (Phi[:, :, 0] * x[..., :1] + Phi[:, :, 1] * x[..., 1:]  # Phi x, 9x faster than einsum here
                 + G0 * u[..., None] + Gr * (u_next - u)[..., None])
            u = u_next
    return out


def modal_frf(omega, zeta, outputs, inputs, f_hz):
    """Accelerance by the modal sum at ``f_hz``: (p, c), (m/s^2)/N, for the single input ``inputs`` (m,)."""
    w = 2 * np.pi * np.asarray(f_hz)[:, None]
    receptance = (outputs[None] * (inputs / (omega**2 - w**2 + 2j * zeta * omega * w))[:, None, :]).sum(axis=2)
    return -(w**2) * receptance


def simulate(omega, zeta, outputs, hammer, ambient, rng, hits=HITS, fs=SAMPLE_RATE_HZ, record_s=RECORD_S,
             oversample=OVERSAMPLE, noise=True):
    """Force (h, t) in N and accelerations (h, c, t) in m/s^2 of ``hits`` hits, sampled at ``fs``."""
    from scipy.signal import resample_poly

    n = int(round(record_s * fs))
    dt = 1.0 / (fs * oversample)
    t = np.arange(n * oversample) * dt
    force = np.zeros((hits, 2, t.size))
    for h in range(hits):
        duration = PULSE_S * rng.uniform(0.9, 1.1)
        start = PRETRIGGER_S + rng.uniform(0, 1 / fs)
        inside = (t >= start) & (t <= start + duration)
        force[h, 0, inside] = PEAK_FORCE_N * rng.uniform(0.7, 1.3) * np.sin(np.pi * (t[inside] - start) / duration)
        if noise:
            force[h, 1] = AMBIENT * PEAK_FORCE_N * np.sqrt(oversample) * rng.standard_normal(t.size)
    inputs = np.column_stack([hammer, ambient])
    acc = modal_accelerations(omega, zeta, outputs, inputs, force, dt)
    # The analyser's anti-alias filter and decimation, the same on every channel.
    measured_force = resample_poly(force[:, 0], 1, oversample, axis=-1)
    acc = resample_poly(acc, 1, oversample, axis=-1)
    if noise:
        measured_force = measured_force + FORCE_NOISE * PEAK_FORCE_N * rng.standard_normal(measured_force.shape)
        floor = FLOOR * np.max(np.abs(acc), axis=(0, 2))
        acc = acc + floor[None, :, None] * rng.standard_normal(acc.shape)
    return measured_force, acc


def main() -> int:
    from fe_core.benchmark import ALPHA_ACTUAL
    from fe_core.io import read_model
    from tasks.io.measured import read_measured
    from tasks.io.measured.time_records import write_uff
    from tasks.io.measured.units import G

    t0, c0 = time.perf_counter(), time.process_time()
    model = read_model(MODEL)
    hammer = model.excitation_test_dofs.index((HAMMER_NODE, 3))
    omega, zeta, phi = modal_basis(model.stiffness(ALPHA_ACTUAL).toarray(), model.mass().toarray(), model.damping)
    outputs = (model.sensor_loads().T @ phi)                      # (c, m)
    hammer_shape = phi.T @ model.excitation_loads[:, hammer]      # (m,)
    node = int(np.argmin(np.linalg.norm(model.mesh.nodes - np.array(AMBIENT_POINT), axis=1)))
    ambient_dof = np.flatnonzero(model.free_dofs == 3 * node + 2)
    ambient_shape = phi[ambient_dof[0]]                           # (m,): a unit force along z at that node
    check_f = np.array([50.0, 137.0, 250.0, 333.0])
    direct = -((2 * np.pi * check_f[:, None]) ** 2) * model.frf_channels(
        ALPHA_ACTUAL, check_f, np.arange(model.n_sensors), np.full(model.n_sensors, hammer), method="direct")
    modal_check = np.max(np.abs(modal_frf(omega, zeta, outputs, hammer_shape, check_f) - direct) / np.abs(direct))
    print(f"{omega.size} modes ({omega[0] / 2 / np.pi:.1f} Hz .. {omega[-1] / 2 / np.pi:.3g} Hz); modal sum vs direct "
          f"solve at {check_f.size} lines: max relative difference {modal_check:.1e}")
    force, acc = simulate(omega, zeta, outputs, hammer_shape, ambient_shape, np.random.default_rng(SEED))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    labels = [f"{node}:+z" for node, _ in model.sensor_test_dofs]
    tmp = OUT.with_name(OUT.name + ".tmp.uff")
    write_uff(tmp, SAMPLE_RATE_HZ, force, acc / G, labels, f"{HAMMER_NODE}:+z", response_unit="g",
              id_text="benchmarks.make.hammer_records")
    tmp.replace(OUT)
    measured = read_measured(OUT)
    f = measured.frequencies_hz
    exact = modal_frf(omega, zeta, outputs, hammer_shape, f) / -((2 * np.pi * f[:, None]) ** 2)
    rel = np.abs(measured.complex_frf - exact) / np.abs(exact)
    good = measured.coherence >= 0.9
    print(f"wrote {OUT.relative_to(REPO)} ({OUT.stat().st_size / 1e3:.0f} kB): {HITS} hits x (force + "
          f"{len(labels)} accelerations) x {int(RECORD_S * SAMPLE_RATE_HZ)} samples at {SAMPLE_RATE_HZ:g} Hz")
    print(f"H1 of the records vs the exact FRF at {f.size} lines {f[0]:g}..{f[-1]:g} Hz: median relative error "
          f"{np.median(rel):.4f}, rms where coherence >= 0.9 {np.sqrt(np.mean(rel[good] ** 2)):.4f} "
          f"({good.sum()} of {good.size} values); coherence {measured.coherence.min():.3g}..1")
    print(f"time {time.perf_counter() - t0:.1f} s wall, {time.process_time() - c0:.1f} s CPU")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.hammer_records", __doc__)
    sys.exit(main())
