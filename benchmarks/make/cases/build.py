"""Build the structures' model files and the cases' data (``python -m benchmarks.make.cases``)."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.make.cases import case as cs
from benchmarks.make.cases import deck as dk
from benchmarks.make.cases import fem_data as fd
from benchmarks.make.cases import noise

N_NOMINAL = 14


def _rel(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(cs.REPO))
    except ValueError:
        return str(path)


def _mesh_hash(s: dict) -> str:
    h = hashlib.sha256()
    for a in (np.round(s["model_nodes"], 12), s["model_cells"], np.round(s["data_nodes"], 12), s["data_cells"]):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def load_structure(name: str):
    """The solid structure (meshes made again by gmsh; the same as the committed model's, checked by hash)."""
    from benchmarks.make.cases import solids

    return solids.structure(name)


def structure_info(name: str, root: Path = cs.ROOT, rebuild: bool = False) -> dict:
    """``structures/<name>/structure.json`` (built with the model files when missing or ``rebuild``)."""
    folder = root / "structures" / name
    file = folder / "structure.json"
    if file.exists() and not rebuild:
        return json.loads(file.read_text())
    t0 = time.perf_counter()
    if name == "channel_deck":
        K, M, outputs, load, labels, _ = dk.matrices(np.zeros(len(dk.SEGMENTS)))
        f = fd.modes(K, M, 1.0, start=N_NOMINAL)[0][:N_NOMINAL]
        damping = fd.rayleigh(f[0], f[9], dk.ZETA)
        facts = dk.write_model(folder, damping)
        ux = (labels[:, 1] == 1).astype(float)
        info = {"name": name, "description": "aluminium C-channel of S8R shells (web 100 mm, flanges 40 mm, 2.5 mm), "
                                            "0.8 m, cantilevered", "kind": "deck", "size_m": dk.L,
                "mass_kg": float(ux @ (M @ ux)), "segments": dk.SEGMENTS, "zeta": dk.ZETA,
                "data": f"ccx's matrices of the deck meshed {dk.DATA_MESH} (cells along x, web, flange): "
                        f"{K.shape[0]} rows", "model_mesh": list(dk.MODEL_MESH), "data_mesh": list(dk.DATA_MESH),
                "support": "every node at x = 0 held (*BOUNDARY 1-6)", **facts}
    else:
        from benchmarks.make.cases.modelfile import write_solid_model

        s = load_structure(name)
        d = fd.data_model(s)
        K, M = fd.assembled(d, np.zeros(len(s["segments"])))
        f = fd.modes(*fd.condensed(K, M, d["free"]), 1.0, start=N_NOMINAL)[0][:N_NOMINAL]
        damping = fd.rayleigh(f[0], f[9], s["zeta"])
        facts = write_solid_model(s, folder, damping)
        info = {"name": name, "description": s["description"], "kind": "solid", "size_m": s["size_m"],
                "mass_kg": fd.total_mass(d), "segments": s["segments"], "zeta": s["zeta"],
                "data": f"scikit-fem {s['data_element']} on {'the model cells' if s['data_element'] == 'Q2' else 'a gmsh mesh of size %g m' % s['sizes'][1]}: "
                        f"{d['basis'].N} DOFs ({d['free'].size} free)", "support": s["support_text"],
                "mesh_sizes_m": list(s.get("sizes") or (0.015, 0.015)), "mesh_hash": _mesh_hash(s), **facts}
    from fe_core.io import read_model

    model = read_model(folder / "model.toml")
    g = model.natural_frequencies(np.zeros(model.n_segments), N_NOMINAL)
    info.update(damping=list(damping), model=_rel(folder / "model.toml"), model_free_dofs=int(model.n_dofs),
                data_nominal_hz=np.round(f, 3).tolist(), model_nominal_hz=np.round(g, 3).tolist(),
                model_minus_data_percent=np.round(100 * (g / f - 1), 3).tolist(),
                build_seconds=round(time.perf_counter() - t0, 1))
    file.write_text(json.dumps(info, indent=1) + "\n")
    return info


def _lines(f_modes, n: int) -> tuple[np.ndarray, float]:
    """Lines from 0 Hz to the band's top (midway between modes n and n + 1) at 0.5 Hz (top <= 400 Hz) or 1 Hz."""
    top = (f_modes[n - 1] + f_modes[n]) / 2
    step = 0.5 if top <= 400 else 1.0
    top = np.ceil(top / step) * step
    return np.arange(int(round(top / step)) + 1) * step, step


def make_case(spec: dict, root: Path = cs.ROOT) -> dict:
    """Write ``<root>/<set>/<id>/measured.csv`` and ``truth.json``; returns the truth."""
    t0 = time.perf_counter()
    info = structure_info(spec["structure"], root)
    dr = cs.draw(spec, len(info["segments"]))
    damping = tuple(info["damping"])
    top_guess = fd.MODES_UP_TO * 1.3 * info["data_nominal_hz"][dr["band_modes"]]
    if spec["structure"] == "channel_deck":
        src = cs._deck(spec, dr)
        systems = {"with": src["with"], "without": src["base"]}
    else:
        s = {**load_structure(spec["structure"]), "points": spec.get("points", "vertex")}
        if _mesh_hash(s) != info["mesh_hash"]:
            raise RuntimeError(f"{spec['structure']}: gmsh made another mesh than the committed model's "
                               "(rebuild the structures and every case with --structures)")
        if spec.get("data_mesh", "fine") == "model":
            from benchmarks.make.cases.solids import on_model_mesh

            s = on_model_mesh(s)
        src = cs._solid(spec, s, dr, info)
        systems = {}
        for key, (xK, xM) in {"with": (src["extra_K"], src["extra_M"]), "without": (None, None)}.items():
            d = src["d"] if key == "with" else fd.data_model(s)
            K, M = fd.assembled(d, src["alpha"], xK, xM)
            Kc, Mc = fd.condensed(K, M, d["free"])
            systems[key] = (Kc, Mc, d["outputs"][:, d["free"]], d["load"][d["free"]])
    clean = spec["kind"] == "none"
    sp_with = fd.spectral(*systems["with"], top_guess)
    sp_without = sp_with if clean else fd.spectral(*systems["without"], top_guess)
    lines, step = _lines(sp_with["f"], dr["band_modes"])
    f = lines[1:]
    H = fd.modal_frf(sp_with, damping, f)
    H0 = fd.modal_frf(sp_without, damping, f)
    # the check: the equilibrium residual at the line nearest the band's middle mode and at the top
    k_mid = dr["band_modes"] // 2
    line = float(f[np.argmin(np.abs(f - sp_with["f"][k_mid]))])
    Kc, Mc, _, load = systems["with"]
    check = max(fd.equilibrium_residual(sp_with, Kc, Mc, load, damping, x) for x in (line, float(f[-1])))
    acc = np.zeros((lines.size, H.shape[1]), complex)
    acc[1:] = -((2 * np.pi * f[:, None]) ** 2) * H
    n_ch = H.shape[1]
    averages = np.full(n_ch, dr["averages"])
    fewer = [int(c) for c in dr["fewer_channels"] if c < n_ch][:dr["fewer"]]
    averages[fewer] = max(2, dr["averages"] // 3)
    settings = {"relative": dr["relative"], "floor": dr["floor"], "force": dr["force"],
                "channel_averages": averages.tolist()}
    H1, coherence = noise.simulate(acc, lines, settings, np.random.default_rng(dr["noise_seed"]))
    sensors = _sensor_names(spec["structure"])
    folder = root / spec["set"] / spec["id"]
    sha = noise.write_table(folder / "measured.csv", sensors, lines, H1, coherence, averages,
                            [f"held-out case {spec['id']} (issue 40): python -m benchmarks.make.cases --set "
                             f"{spec['set']} --only {spec['id']}",
                             f"impact test, hammer at '{_exc_name(spec['structure'])}'; averages per channel: "
                             + ", ".join(f"{n}={a}" for n, a in zip(sensors, averages))])
    rel = np.abs(H1[1:] / acc[1:] - 1)
    zeta_k = (damping[0] / (2 * np.pi * sp_with["f"]) + damping[1] * 2 * np.pi * sp_with["f"]) / 2
    n_cmp = min(dr["band_modes"] + 1, sp_with["f"].size, sp_without["f"].size)
    shift = (sp_with["f"][:n_cmp] - sp_without["f"][:n_cmp])
    truth = {
        "case": spec["id"], "set": spec["set"], "seed": spec["seed"], "structure": spec["structure"],
        "points": spec.get("points", "vertex"), "data_mesh": spec.get("data_mesh", "fine"),
        "model": info["model"], "measured": _rel(folder / "measured.csv"), "measured_sha256": sha,
        "expected": spec["expected"], "in_library": spec["kind"] in ("point_mass", "mount", "patch"),
        "segments": info["segments"], "factors": np.round(src["alpha"], 6).tolist(),
        "effect": _clean_json(src["effect"]), "structure_size_m": info["size_m"], "structure_mass_kg": src["mass"],
        "noise": {"response_relative": dr["relative"], "floor_of_channel_peak": dr["floor"],
                  "force_relative": dr["force"], "averages": dr["averages"], "channel_averages": averages.tolist(),
                  "realised_median_relative_error": float(np.median(rel)),
                  "values_with_coherence_below_0.9": int((coherence[1:] < 0.9).sum()), "values": int(rel.size)},
        "lines": {"kind": "accelerance", "step_hz": step, "top_hz": float(lines[-1]), "count": int(lines.size),
                  "modes_in_band": dr["band_modes"]},
        "natural_frequencies_hz": np.round(sp_with["f"][:dr["band_modes"] + 1], 4).tolist(),
        "effect_frequency_shift_percent": np.round(100 * shift / sp_without["f"][:n_cmp], 4).tolist(),
        "effect_shift_in_half_power_bandwidths": np.round(shift / (2 * zeta_k[:n_cmp] * sp_without["f"][:n_cmp]), 3).tolist(),
        "effect_rms_log_amplitude_change": float(np.sqrt(np.mean(np.log(np.abs(H) / np.abs(H0)) ** 2))),
        "check_equilibrium_residual": {"lines_hz": [line, float(f[-1])], "largest_relative": check},
        "modes_superposed": int(sp_with["f"].size), "seconds": round(time.perf_counter() - t0, 1)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return truth


def _clean_json(x):
    if isinstance(x, dict):
        return {k: _clean_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean_json(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x


def _sensor_names(structure: str) -> list[str]:
    if structure == "channel_deck":
        return [n for n, _, _ in dk.SENSORS]
    from benchmarks.make.cases.solids import SOLIDS

    return [n for n, _, _ in SOLIDS[structure]()["sensors"]]


def _exc_name(structure: str) -> str:
    if structure == "channel_deck":
        return dk.EXCITATION[0]
    from benchmarks.make.cases.solids import SOLIDS

    return SOLIDS[structure]()["excitation"][0]
