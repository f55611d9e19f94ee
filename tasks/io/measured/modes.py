"""Measured modes (an EMA or OMA result): UFF dataset 55 and a CSV table, in one internal form.

**UFF** (``.uff``/``.unv``): one dataset 55 ("data at nodes") per mode, as modal exports write them, with a
dataset 151 (header), 164 (units) and 15 (test nodes' coordinates) around them. Record 6 must declare a
normal mode (analysis type 2) or a complex mode (3 or 7); a static (1), buckling (6), transient (4) or
frequency-response (5) dataset 55 is refused naming the dataset. Record 7/8 give the mode number, the
frequency (Hz) and, for normal modes, the modal viscous damping ratio. Each node carries 3 (or 6) values:
u_x, u_y, u_z (rotations are not used). A direction that is zero at every node of every mode was not
measured; the others are test DOFs ``NODE:+x|+y|+z``.

**Complex modes** (analysis types 3 and 7: eigenvalue ``lambda = -zeta w + i w sqrt(1 - zeta^2)``,
complex shape) are reduced to real ones by a stated rule: the shape is turned by the angle that makes
its real part largest (``theta = angle(sum phi_j^2) / 2``, the principal axis of the points phi_j in the
complex plane) and its real part is kept; ``f = |lambda| / 2 pi``, ``zeta = -Re(lambda) / |lambda|``.
What the imaginary part held (1 - MPC, the modal phase collinearity) is kept per mode in ``notes``.

**CSV**: a long table, one row per mode and test DOF::

    mode,frequency_hz,damping_ratio,dof,shape
    1,112.3,0.004,1:+z,0.0123
    1,112.3,0.004,2:+z,0.0311
    ...

``damping_ratio`` may be empty; ``dof`` is ``NODE:DIR`` as in the FRF tables, or the name of a model sensor (as a
table's response column may be); every mode must give a value
at every DOF (write 0 where a mode is at rest, leave out a DOF nobody measured).

A file is modal when it holds a dataset 55 and no dataset 58 FRF (UFF), or has the columns ``mode`` and
``shape`` (CSV): :func:`is_modal_file`. Matching the DOFs to a model's sensors is not done here (see
:mod:`tasks.modal_data`). Problems raise :class:`MeasuredDataError` naming the file and the dataset or line.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .frf import MeasuredDataError, dof_label, parse_dof

__all__ = ["MeasuredModes", "read_modes", "describe_modes", "write_uff55", "write_csv", "is_modal_file", "real_mode",
           "ANALYSIS_TYPES", "MODAL_ANALYSIS_TYPES"]

#: Dataset 55 record 6 field 2.
ANALYSIS_TYPES = {0: "unknown", 1: "static", 2: "normal mode", 3: "complex eigenvalue (first order)",
                  4: "transient", 5: "frequency response", 6: "buckling", 7: "complex eigenvalue (second order)"}
MODAL_ANALYSIS_TYPES = (2, 3, 7)
CSV_COLUMNS = ("mode", "frequency_hz", "damping_ratio", "dof", "shape")


@dataclass(eq=False)
class MeasuredModes:
    """Measured modes at test DOFs.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (n_modes,), Hz, > 0
    damping : ndarray, shape (n_modes,), viscous damping ratio, NaN where not given
    shapes : ndarray, shape (n_modes, n_dofs), real, any scale and sign
    dofs : list of str
        ``NODE:DIR`` label of each column.
    names : list of str
        ``mode <number>`` of each row (the file's mode numbers).
    places : list of str
        Where each mode is in the file (``dataset k``, ``line k``), for messages.
    source : str
    notes : list of str
        What was converted (complex modes, units, skipped datasets).
    nodes : dict
        Test node id -> coordinates (m) from dataset 15, if the file has one.
    """

    frequencies_hz: np.ndarray
    damping: np.ndarray
    shapes: np.ndarray
    dofs: list
    names: list
    places: list
    source: str
    notes: list = field(default_factory=list)
    nodes: dict = field(default_factory=dict)

    @property
    def n_modes(self) -> int:
        return int(self.frequencies_hz.size)


def real_mode(shape: np.ndarray) -> tuple[np.ndarray, float]:
    """The real mode of a complex shape by the stated rule, and its MPC (1 for a real mode).

    ``theta = angle(sum phi_j^2) / 2`` turns the shape so its real part is largest; MPC is
    ``|Re|^2 / |phi|^2`` after the turn.
    """
    shape = np.asarray(shape, dtype=complex)
    theta = 0.5 * np.angle(np.sum(shape ** 2))
    turned = shape * np.exp(-1j * theta)
    total = float(np.sum(np.abs(shape) ** 2))
    return turned.real.copy(), float(np.sum(turned.real ** 2) / total) if total > 0 else 1.0


def is_modal_file(path) -> bool:
    """Whether a measured file holds modes (UFF dataset 55 without FRFs; CSV with ``mode`` and ``shape``)."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix in (".uff", ".unv"):
            import pyuff

            types = list(pyuff.UFF(str(path)).get_set_types())
            return 55 in types and 58 not in types
        if suffix == ".csv":
            with open(path, newline="") as fh:
                header = next(csv.reader(fh), [])
            names = {h.strip().lower() for h in header}
            return {"mode", "shape"} <= names
    except Exception:  # an unreadable file is the FRF readers' to report
        return False
    return False


def read_modes(path) -> MeasuredModes:
    """Read a modal file (UFF datasets 55, or the CSV table); see the module docstring."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(2, "no such file", str(path))
    suffix = path.suffix.lower()
    modes = _read_uff(path) if suffix in (".uff", ".unv") else _read_csv(path)
    _check(modes)
    return modes


def _read_uff(path: Path) -> MeasuredModes:
    import pyuff

    try:
        uff = pyuff.UFF(str(path))
        types = list(uff.get_set_types())
    except Exception as exc:
        raise MeasuredDataError(f"{path}: not a UFF file ({exc})") from None
    freqs, damping, columns, names, places, notes, nodes = [], [], [], [], [], [], {}
    for k, set_type in enumerate(types):
        place = f"dataset {k + 1}"
        if set_type not in (55, 164, 15):
            if set_type != 151:
                notes.append(f"{place} (type {set_type}) is not used for modes")
            continue
        try:
            d = uff.read_sets(k)
        except Exception as exc:
            raise MeasuredDataError(f"{path}: {place}: unreadable dataset {set_type} ({exc})") from None
        if set_type == 164:
            if d.get("units_code", 1) != 1:
                notes.append(f"{place}: units code {d.get('units_code')}: mode shapes are compared "
                             "scale-free, frequencies are in Hz in every unit system")
            continue
        if set_type == 15:
            for n, x, y, z in zip(d["node_nums"], d["x"], d["y"], d["z"]):
                nodes[int(n)] = (float(x), float(y), float(z))
            continue
        kind = int(d.get("analysis_type", 0))
        if kind not in MODAL_ANALYSIS_TYPES:
            raise MeasuredDataError(f"{path}: {place}: dataset 55 of analysis type {kind} "
                                    f"({ANALYSIS_TYPES.get(kind, 'unknown code')}) is not a mode; mode shapes "
                                    "are analysis type 2 (normal mode) or 3/7 (complex mode)")
        node_nums = np.asarray(d["node_nums"], dtype=int)
        values = np.stack([np.asarray(d[f"r{j}"]) for j in (1, 2, 3)], axis=1)  # (n_nodes, 3)
        if kind == 2:
            f, zeta = float(d["freq"]), float(d.get("modal_damp_vis", np.nan))
        else:
            lam = complex(d["eig"])
            f, zeta = abs(lam) / (2 * np.pi), -lam.real / abs(lam) if abs(lam) > 0 else np.nan
        if not np.all(np.isfinite(values)):
            node = int(node_nums[np.flatnonzero(~np.all(np.isfinite(values), axis=1))[0]])
            raise MeasuredDataError(f"{path}: {place} (mode {d.get('mode_n')}): the shape is not finite at node "
                                    f"{node}")
        if np.iscomplexobj(values):
            flat, mpc = real_mode(values.ravel())
            values = flat.reshape(values.shape)
            notes.append(f"{place}: complex mode reduced to real (MPC {mpc:.3f})")
        if len(set(node_nums.tolist())) != node_nums.size:
            raise MeasuredDataError(f"{path}: {place}: a node appears twice")
        columns.append({(int(n), j + 1): float(values[i, j]) for i, n in enumerate(node_nums) for j in range(3)})
        freqs.append(f)
        damping.append(zeta)
        names.append(f"mode {int(d.get('mode_n', len(names) + 1))}")
        places.append(place)
    if not freqs:
        raise MeasuredDataError(f"{path}: no mode found (dataset 55 of a normal or complex mode)")
    keys = sorted(set().union(*columns), key=lambda t: (t[0], t[1]))
    for c, place in zip(columns, places):
        if set(c) != set(keys):
            raise MeasuredDataError(f"{path}: {place}: its nodes differ from the other modes' nodes")
    table = np.array([[c[key] for key in keys] for c in columns])
    measured = np.any(table != 0.0, axis=0)  # a direction at rest in every mode was not measured
    keys = [key for key, used in zip(keys, measured) if used]
    return MeasuredModes(np.array(freqs), np.array(damping), table[:, measured],
                         [dof_label(*key) for key in keys], names, places, str(path), notes, nodes)


def _label(dof) -> str:
    return dof if isinstance(dof, str) else dof_label(*dof)


def _dof_order(dof):
    """Test DOFs by node and direction, then sensor names."""
    return (1, dof, 0) if isinstance(dof, str) else (0, "", *dof)


def _read_csv(path: Path) -> MeasuredModes:
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise MeasuredDataError(f"{path}: empty file")
    header = [h.strip().lower() for h in rows[0]]
    missing = [c for c in CSV_COLUMNS if c not in header and c != "damping_ratio"]
    if missing:
        raise MeasuredDataError(f"{path}: line 1: missing column(s) {', '.join(missing)}; a modal table has "
                                f"{', '.join(CSV_COLUMNS)}")
    col = {c: header.index(c) for c in CSV_COLUMNS if c in header}
    modes: dict = {}
    for line, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        where = f"{path}: line {line}"
        try:
            number = int(row[col["mode"]])
            f = float(row[col["frequency_hz"]])
            zeta = float(row[col["damping_ratio"]]) if "damping_ratio" in col and row[col["damping_ratio"]].strip() \
                else np.nan
            value = float(row[col["shape"]])
            label = row[col["dof"]].strip()
            dof = parse_dof(label)
        except (ValueError, IndexError) as exc:
            raise MeasuredDataError(f"{where}: {exc}") from None
        if dof is None and (not label or ":" in label):
            raise MeasuredDataError(f"{where}: dof {label!r} must be NODE:DIR with a translation x, y, z, or the "
                                    "name of a model sensor")
        if dof is not None and not 1 <= abs(dof[1]) <= 3:
            raise MeasuredDataError(f"{where}: dof {label!r} must be NODE:DIR with a translation x, y, z")
        dof = dof if dof is not None else label  # a sensor's name, matched by name (tasks.modal_data)
        if not np.isfinite(value):
            raise MeasuredDataError(f"{where}: mode {number}: the shape is not finite at {_label(dof)}")
        entry = modes.setdefault(number, {"f": f, "zeta": zeta, "line": line, "values": {}})
        if entry["f"] != f:
            raise MeasuredDataError(f"{where}: mode {number} has frequency {f} here and {entry['f']} on line "
                                    f"{entry['line']}")
        if dof in entry["values"]:
            raise MeasuredDataError(f"{where}: mode {number} gives {_label(dof)} twice")
        entry["values"][dof] = value
    if not modes:
        raise MeasuredDataError(f"{path}: no mode found (no data rows)")
    keys = sorted(set().union(*(m["values"] for m in modes.values())), key=_dof_order)
    for number, m in modes.items():
        if set(m["values"]) != set(keys):
            gap = sorted(set(keys) - set(m["values"]))
            raise MeasuredDataError(f"{path}: line {m['line']}: mode {number} has no value at "
                                    f"{', '.join(_label(g) for g in gap)}")
    numbers = sorted(modes)
    return MeasuredModes(np.array([modes[n]["f"] for n in numbers]), np.array([modes[n]["zeta"] for n in numbers]),
                         np.array([[modes[n]["values"][k] for k in keys] for n in numbers]),
                         [_label(k) for k in keys], [f"mode {n}" for n in numbers],
                         [f"line {modes[n]['line']}" for n in numbers], str(path))


def describe_modes(modes: MeasuredModes) -> str:
    """Summary lines: modes, frequencies, damping, test DOFs and what was converted."""
    lines = [f"{modes.source}: {modes.n_modes} modes at {len(modes.dofs)} test DOFs "
             f"({', '.join(modes.dofs[:4])}{', ...' if len(modes.dofs) > 4 else ''})"]
    for name, f, z in zip(modes.names, modes.frequencies_hz, modes.damping):
        lines.append(f"  {name}: {f:.4g} Hz" + ("" if not np.isfinite(z) else f", damping ratio {z:.3g}"))
    lines += [f"  {note}" for note in modes.notes]
    return "\n".join(lines)


def _check(modes: MeasuredModes) -> None:
    for k, (f, place) in enumerate(zip(modes.frequencies_hz, modes.places)):
        if not np.isfinite(f) or f <= 0:
            raise MeasuredDataError(f"{modes.source}: {place} ({modes.names[k]}): frequency {f} Hz is not a "
                                    "positive number")
        if not np.any(modes.shapes[k] != 0):
            raise MeasuredDataError(f"{modes.source}: {place} ({modes.names[k]}): the shape is zero everywhere")


def write_uff55(path, modes: MeasuredModes, complex_shapes: bool = False) -> Path:
    """Write modes as a UFF file: dataset 151 (header), 164 (SI units), then one dataset 55 per mode.

    Test DOFs ``NODE:+x|+y|+z`` become the node's r1..r3 (other directions 0). With ``complex_shapes`` each
    mode is written as a complex mode (analysis type 3) with its eigenvalue from frequency and damping.
    """
    import pyuff

    nodes = sorted({parse_dof(d)[0] for d in modes.dofs})
    sets = [pyuff.prepare_151(model_name="measured modes", description="modes at test nodes", db_app="fe-update",
                              date_db_created="", time_db_created="", version_db1=1, version_db2=0,
                              file_type=0, date_db_saved="", time_db_saved="", program="fe-update",
                              date_db_written="", time_db_written=""),
            pyuff.prepare_164(units_code=1, units_description="SI", temp_mode=1, length=1.0, force=1.0,
                              temp=1.0, temp_offset=273.15)]
    if modes.nodes:
        ids = sorted(modes.nodes)
        xyz = np.array([modes.nodes[i] for i in ids], dtype=float)
        sets.append(pyuff.prepare_15(node_nums=np.array(ids), def_cs=np.zeros(len(ids), int),
                                     disp_cs=np.zeros(len(ids), int), color=np.ones(len(ids), int),
                                     x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2]))
    for k in range(modes.n_modes):
        r = np.zeros((len(nodes), 3))
        for d, v in zip(modes.dofs, modes.shapes[k]):
            node, direction = parse_dof(d)
            r[nodes.index(node), abs(direction) - 1] = np.sign(direction) * v
        zeta = 0.0 if not np.isfinite(modes.damping[k]) else float(modes.damping[k])
        number = int(modes.names[k].split()[-1]) if modes.names[k].split()[-1].isdigit() else k + 1
        common = dict(model_type=1, data_ch=2, spec_data_type=8, load_case=1, mode_n=number,
                      node_nums=np.array(nodes), id1="measured mode", id2="", id3="", id4="", id5="")
        if complex_shapes:
            w = 2 * np.pi * modes.frequencies_hz[k]
            eig = complex(-zeta * w, w * np.sqrt(1 - zeta ** 2))
            c = r.astype(complex) * np.exp(0.3j)
            sets.append(pyuff.prepare_55(analysis_type=3, eig=eig, modal_a=0j, modal_b=0j, data_type=5,
                                         r1=c[:, 0], r2=c[:, 1], r3=c[:, 2], **common))
        else:
            sets.append(pyuff.prepare_55(analysis_type=2, freq=float(modes.frequencies_hz[k]), modal_m=0.0,
                                         modal_damp_vis=zeta, modal_damp_his=0.0, data_type=2,
                                         r1=r[:, 0], r2=r[:, 1], r3=r[:, 2], **common))
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite")
    return Path(path)


def write_csv(path, modes: MeasuredModes) -> Path:
    """Write modes as the CSV table of the module docstring."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        for k in range(modes.n_modes):
            number = modes.names[k].split()[-1]
            zeta = "" if not np.isfinite(modes.damping[k]) else repr(float(modes.damping[k]))
            for d, v in zip(modes.dofs, modes.shapes[k]):
                w.writerow([number, repr(float(modes.frequencies_hz[k])), zeta, d, repr(float(v))])
    return Path(path)
