"""The internal form of measured FRFs, the FRF kinds, channel labels, and long rows -> grid.

Every reader (:mod:`.table` for CSV and Parquet, :mod:`.uff` for UFF58)
turns its file into long rows (one per channel and frequency line) with the
place of each row in the file, and :func:`grid_from_rows` checks them and
builds one :class:`MeasuredFRF`: receptance on a complete (line, channel)
grid, whatever kind the file held. What was converted or dropped on the way
is kept in ``MeasuredFRF.notes`` (logged, and written to a run's manifest).

A channel is a (response, reference) pair. Labels are either names (of the
model file's ``[[sensors]]`` and ``[[excitations]]``) or ``"NODE:DIR"``, a
test node and a direction (``101:+z``; see :func:`parse_dof`), matched to the
model through its ``test_node`` keys when the data meet a model
(:mod:`tasks.update_data`). The legacy form (a ``sensor`` column, or UFF58
without a reference node) has no labels: channel ``k`` is the model's sensor
``k`` under its default excitation.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .problems import MeasuredDataError, Problems

__all__ = [
    "MeasuredDataError", "MeasuredFRF", "KINDS", "AMPLITUDE_RTOL", "kind_of", "to_receptance",
    "from_receptance", "parse_dof", "dof_label", "grid_from_rows", "first_bad",
]

#: Allowed relative gap between ``amplitude`` and ``hypot(real, imag)``.
AMPLITUDE_RTOL = 1e-6

#: FRF kinds, response over force: displacement (m/N), velocity ((m/s)/N), acceleration ((m/s^2)/N).
KINDS = ("receptance", "mobility", "accelerance")
_KIND_NAMES = {
    "receptance": "receptance", "compliance": "receptance", "displacement": "receptance", "m/n": "receptance",
    "mobility": "mobility", "velocity": "mobility", "m/s/n": "mobility", "(m/s)/n": "mobility",
    "accelerance": "accelerance", "inertance": "accelerance", "acceleration": "accelerance",
    "m/s^2/n": "accelerance", "(m/s^2)/n": "accelerance", "m/s2/n": "accelerance",
}
#: Power of (j w) that turns a receptance into each kind (the units a test system measures it in).
POWER = {"receptance": 0, "mobility": 1, "accelerance": 2}


def kind_of(text) -> str | None:
    """The FRF kind a name or unit stands for (``"accelerance"``, ``"m/s^2/N"``, ...), or None."""
    if not isinstance(text, str):
        return None
    return _KIND_NAMES.get(text.strip().lower().replace(" ", ""))


def to_receptance(values, frequencies_hz, kind: str):
    """Convert FRF values of ``kind`` to receptance, m/N.

    ``H_d = H / (j w)^k`` with ``k`` = 0, 1, 2 for receptance, mobility,
    accelerance. Complex values are divided by the complex factor, real
    values (amplitudes) by its modulus ``w^k``. Frequencies must be > 0.

    Parameters
    ----------
    values : ndarray, shape (..., p) or broadcastable with ``frequencies_hz``
    frequencies_hz : ndarray, Hz
    kind : {"receptance", "mobility", "accelerance"}
    """
    k = POWER[kind]
    if k == 0:
        return values
    jw = 2j * np.pi * np.asarray(frequencies_hz, float)
    factor = jw**k if np.iscomplexobj(values) else np.abs(jw) ** k
    return values / factor


def from_receptance(values, frequencies_hz, kind: str):
    """The inverse of :func:`to_receptance`: receptance (m/N) to ``kind``."""
    k = POWER[kind]
    if k == 0:
        return values
    jw = 2j * np.pi * np.asarray(frequencies_hz, float)
    factor = jw**k if np.iscomplexobj(values) else np.abs(jw) ** k
    return values * factor


# -- channel labels ----------------------------------------------------------------------------
#: UFF58 direction codes (record 6 fields 7 and 10) and their names.
DIRECTION_NAMES = {1: "x", 2: "y", 3: "z", 4: "rx", 5: "ry", 6: "rz"}
_DIRECTION_CODES = {name: code for code, name in DIRECTION_NAMES.items()}
_DOF = re.compile(r"^\s*(\d+)\s*:\s*([+-]?)\s*([a-z]+|\d)\s*$", re.IGNORECASE)


def parse_dof(label: str) -> tuple[int, int] | None:
    """``(test node, signed direction code)`` of a ``"NODE:DIR"`` label; None for a name.

    DIR is ``x``, ``y``, ``z`` (rotations ``rx``, ``ry``, ``rz``) with an
    optional sign, or a UFF58 code ``1 .. 6`` with an optional sign (``0``: a
    scalar). ``"101:-z"`` gives ``(101, -3)``.

    Raises
    ------
    ValueError
        For a label with a colon that is not a node and direction.
    """
    if ":" not in label:
        return None
    match = _DOF.match(label)
    if not match:
        raise ValueError(f"{label!r} is neither a name nor NODE:DIRECTION (e.g. 101:+z)")
    node, sign, direction = int(match.group(1)), match.group(2), match.group(3).lower()
    code = int(direction) if direction.isdigit() else _DIRECTION_CODES.get(direction)
    if code is None or code > 6:
        raise ValueError(f"{label!r}: unknown direction {direction!r}; use x, y, z (or 1, 2, 3) with a sign")
    return node, -code if sign == "-" else code


def dof_label(node: int, direction: int) -> str:
    """The canonical label of a test node and signed direction code: ``(101, -3)`` -> ``"101:-z"``."""
    if direction == 0:
        return f"{node}:0"
    return f"{node}:{'-' if direction < 0 else '+'}{DIRECTION_NAMES[abs(direction)]}"


# -- the internal form -------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MeasuredFRF:
    """Measured FRFs on a complete (frequency line, channel) grid, as receptance.

    Arrays are read-only copies, checked on construction. The first five
    fields are the legacy form's (one channel per model sensor, the model's
    default excitation); the others default to it.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (p,), Hz
        Strictly increasing, > 0.
    sensors : ndarray, shape (n,), int
        Channel numbers: in the legacy form the 1-based model sensor of each
        column (ascending when read), otherwise ``1 .. n`` in file order.
    amplitude : ndarray, shape (p, n), m/N
        Modulus of the receptance, > 0; column ``j`` is channel ``sensors[j]``.
    complex_frf : ndarray, shape (p, n), complex, m/N, or None
        The complex receptance when the file has phase; ``abs(complex_frf)``
        equals ``amplitude`` to ``AMPLITUDE_RTOL``.
    source : str
        Where the data came from (the file path), for messages.
    responses : tuple of str, length n, or None
        Response label of each channel (a sensor name or ``"NODE:DIR"``);
        None in the legacy form.
    references : tuple of (str or None), length n, or None
        Reference label of each channel; None (the tuple or an entry) means
        the model's default excitation.
    coherence : ndarray, shape (p, n), or None
        Ordinary coherence in [0, 1] per line and channel, when measured.
    kinds : tuple of str, length n, or None
        The kind each channel had in the file (:data:`KINDS`); None = all
        receptance.
    places : tuple of str, length n, or None
        Where each channel's first row is in the file ("line 2", "dataset 3").
    line_places : tuple of str, length p, or None
        Where each frequency line first appears in the file.
    notes : tuple of str
        What was converted or dropped while reading, one sentence each.
    units : tuple of str, length n, or None
        The unit each channel had in the file (``"g/N"``), before the conversion to SI; None = SI.
    averages : ndarray, shape (n,), int, or None
        Number of averages (hits) behind each channel's FRF and coherence, when the file says or the user
        gave it (``--averages``); with the coherence it gives the noise per line
        (:func:`fe_core.inference.coherence_noise.frf_random_error`).
    """

    frequencies_hz: np.ndarray
    sensors: np.ndarray
    amplitude: np.ndarray
    complex_frf: np.ndarray | None = None
    source: str = ""
    responses: tuple | None = None
    references: tuple | None = None
    coherence: np.ndarray | None = None
    kinds: tuple | None = None
    places: tuple | None = None
    line_places: tuple | None = None
    notes: tuple = ()
    units: tuple | None = None
    averages: np.ndarray | None = None

    def __post_init__(self):
        f = _read_only(self.frequencies_hz, float)
        raw_sensors = np.asarray(self.sensors)
        s = _read_only(raw_sensors, np.int64)
        a = _read_only(self.amplitude, float)
        c = None if self.complex_frf is None else _read_only(self.complex_frf, complex)
        g = None if self.coherence is None else _read_only(self.coherence, float)
        if f.ndim != 1 or not np.all(np.isfinite(f) & (f > 0)) or np.any(np.diff(f) <= 0):
            raise ValueError("frequencies_hz must be 1-D, finite, > 0 and strictly increasing")
        if s.ndim != 1 or np.any(s != raw_sensors) or np.any(s < 1) or np.unique(s).size != s.size:
            raise ValueError("sensors must be 1-D distinct integers >= 1")
        if a.shape != (f.size, s.size) or not np.all(np.isfinite(a) & (a > 0)):
            raise ValueError(f"amplitude must be finite, > 0, shape {(f.size, s.size)}")
        if c is not None and (
            c.shape != a.shape
            or not np.all(np.isfinite(c))
            or np.any(np.abs(a - np.abs(c)) > AMPLITUDE_RTOL * np.abs(c))
        ):
            raise ValueError("complex_frf must be finite, shaped as amplitude, abs == amplitude")
        if g is not None and (g.shape != a.shape or not np.all((g >= 0) & (g <= 1))):
            raise ValueError("coherence must be shaped as amplitude, with values in [0, 1]")
        n = s.size
        if self.averages is not None:
            raw = np.asarray(self.averages)
            v = _read_only(raw, np.int64)
            if v.shape != (n,) or np.any(v != raw) or np.any(v < 1):
                raise ValueError(f"averages must be whole numbers >= 1, one per channel ({n})")
            object.__setattr__(self, "averages", v)
        for name, value in (("responses", self.responses), ("references", self.references),
                            ("kinds", self.kinds), ("places", self.places), ("units", self.units)):
            if value is not None and len(value) != n:
                raise ValueError(f"{name} must have one entry per channel ({n})")
        if self.line_places is not None and len(self.line_places) != f.size:
            raise ValueError("line_places must have one entry per frequency line")
        if self.references is not None and self.responses is None:
            raise ValueError("references need responses (the legacy form has neither)")
        if self.kinds is not None and not set(self.kinds) <= set(KINDS):
            raise ValueError(f"kinds must be among {KINDS}")
        if self.responses is not None:
            pairs = list(zip(self.responses, self.references or (None,) * n))
            if len(set(pairs)) != n:
                raise ValueError("two channels have the same (response, reference)")
        names = ("frequencies_hz", "sensors", "amplitude", "complex_frf", "coherence")
        for name, value in zip(names, (f, s, a, c, g)):
            object.__setattr__(self, name, value)
        for name in ("responses", "references", "kinds", "places", "line_places", "notes", "units"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, tuple(value))

    @property
    def n_channels(self) -> int:
        return int(self.sensors.size)

    @property
    def legacy(self) -> bool:
        """The legacy form: channel k is model sensor k under the model's default excitation, no labels."""
        return self.responses is None

    def channel_label(self, j: int) -> str:
        """``"s1 / hammer"``, ``"3:+z / 1:+z"``, or ``"sensor 3"`` (legacy) for column ``j``."""
        if self.responses is None:
            return f"sensor {int(self.sensors[j])}"
        ref = (self.references or (None,) * self.n_channels)[j]
        return f"{self.responses[j]} / {ref if ref is not None else 'default excitation'}"

    def place(self, j: int) -> str:
        """Where channel ``j`` starts in the file, for messages."""
        return self.places[j] if self.places else f"channel {int(self.sensors[j])}"


def _read_only(values, dtype):
    array = np.array(values, dtype=dtype)
    array.setflags(write=False)
    return array


# -- long rows -> grid -------------------------------------------------------------------------
def first_bad(mask, values, problem, where, source, problems: Problems | None = None):
    """Name the first row where ``mask`` holds and how many more there are: raise, or add to ``problems``."""
    bad = np.flatnonzero(mask)
    if bad.size:
        more = f" ({bad.size - 1} more rows like it)" if bad.size > 1 else ""
        value = values[bad[0]]
        value = value.item() if hasattr(value, "item") else value
        message = f"{source}: {where[bad[0]]}: {problem.format(value)}{more}"
        if problems is None:
            raise MeasuredDataError(message)
        problems.add(message)


def grid_from_rows(columns: dict, where: list[str], source: str, kinds=None, complex_data=None,
                   file_notes=(), units=None, problems: Problems | None = None, bad_rows=None) -> MeasuredFRF:
    """Check long rows and reshape them to a :class:`MeasuredFRF` (receptance).

    Parameters
    ----------
    columns : dict of str to ndarray, shape (r,)
        ``sensor`` (legacy) or ``response`` (str) and optionally ``reference``
        (str, "" = the default excitation); ``frequency_hz``; ``amplitude``
        and/or ``real``, ``imag``; optionally ``coherence`` and ``averages`` (a whole number per channel)
        (all float).
    where : list of str, length r
        Place of each row in the file.
    source : str
    kinds : ndarray of str, shape (r,), optional
        The kind of each row (default receptance).
    complex_data : ndarray of complex, shape (r,), optional
        Complex values given directly (UFF); else built from ``real``, ``imag``.
    file_notes : sequence of str
        Notes of the reader to keep.
    units : ndarray of str, shape (r,), optional
        The unit each row had in the file (values already converted to SI); one per channel.
    problems : Problems, optional
        The reader's problems so far, reported with these checks' in one message.
    bad_rows : ndarray of bool, shape (r,), optional
        Rows the reader already found faulty (not checked again).
    """
    if not where:
        raise MeasuredDataError(f"{source}: no data rows")
    r = len(where)
    # Every check below runs; each names its first row and counts the others.
    problems = Problems(source) if problems is None else problems
    kinds = np.full(r, "receptance", dtype=object) if kinds is None else np.asarray(kinds, dtype=object)
    numeric = [k for k in ("sensor", "frequency_hz", "amplitude", "real", "imag", "coherence", "averages")
               if k in columns]
    # Rows with no problem yet: a later check does not repeat an earlier one's row.
    ok = np.ones(r, dtype=bool) if bad_rows is None else ~np.asarray(bad_rows, dtype=bool)
    for name in numeric:
        values = columns[name]
        first_bad(ok & ~np.isfinite(values), values, name + " is {!r}", where, source, problems)
        ok &= np.isfinite(values)
    frequency = columns["frequency_hz"]
    legacy = "sensor" in columns
    if legacy:
        sensor = columns["sensor"]
        not_id = ok & ((sensor < 1) | (sensor != np.round(sensor)))
        first_bad(not_id, sensor, "sensor {!r} is not an integer >= 1", where, source, problems)
        ok &= ~not_id
    # A mobility or an accelerance is 0 at 0 Hz by definition: such a line carries no information on
    # the structure (what the file holds there is noise) and the FE model needs f > 0, so it is dropped.
    zero = (frequency == 0) & (kinds != "receptance")
    bad = ok & ((frequency < 0) | ((frequency == 0) & ~zero))
    first_bad(bad, frequency, "frequency_hz {!r} is not > 0", where, source, problems)
    ok &= ~bad
    if complex_data is None and "real" in columns:
        with np.errstate(invalid="ignore"):  # an infinite cell (reported above) gives nan
            complex_data = columns["real"] + 1j * columns["imag"]
    if "amplitude" in columns:
        amplitude = columns["amplitude"]
    else:
        amplitude = np.abs(complex_data)
    bad = ok & (amplitude <= 0) & ~zero
    first_bad(bad, amplitude, "amplitude {!r} is not > 0", where, source, problems)
    ok &= ~bad
    if complex_data is not None and "amplitude" in columns:
        modulus = np.abs(complex_data)
        with np.errstate(divide="ignore", invalid="ignore"):  # real = imag = 0 gives gap inf: reported
            gap = np.abs(amplitude - modulus) / modulus
        gap = np.where(zero, 0.0, gap)
        first_bad(ok & ~(gap <= AMPLITUDE_RTOL), gap, "amplitude and hypot(real, imag) differ by {:.2g} (relative)",
                  where, source, problems)
    coherence = columns.get("coherence")
    if coherence is not None:
        first_bad(ok & ((coherence < 0) | (coherence > 1)), coherence, "coherence {!r} is outside [0, 1]", where,
                  source, problems)
    averages = columns.get("averages")
    if averages is not None:
        bad = ok & ((averages < 1) | (averages != np.round(averages)))
        first_bad(bad, averages, "averages {!r} is not a whole number >= 1", where, source, problems)
        ok &= ~bad

    # Channel keys and duplicates.
    if legacy:
        problems.check()
        keys = [(int(s),) for s in sensor]
    else:
        responses = columns["response"]
        references = columns.get("reference", np.full(r, "", dtype=object))
        canonical = {}  # "3:z", "3:+z" and "3:3" are one DOF: one label, so duplicates are found
        for name, labels in (("response", responses), ("reference", references)):
            for i, label in enumerate(labels):
                if not label and name == "response":
                    problems.add(f"{where[i]}: response is empty")
                if label and label not in canonical:
                    try:
                        dof = parse_dof(label)
                    except ValueError as exc:
                        problems.add(f"{where[i]}: {name} {exc}")
                        dof = None
                    canonical[label] = label if dof is None else dof_label(*dof)
        problems.check()
        keys = [(canonical[resp], canonical[ref] if ref else None) for resp, ref in zip(responses, references)]
    problems.check()
    first_row = {}
    for i, key in enumerate(zip(keys, frequency.tolist())):
        if key in first_row:
            problems.add(f"{where[first_row[key]]} and {where[i]} both give {_describe_key(key[0])} at "
                         f"frequency_hz {key[1]!r}")
        else:
            first_row[key] = i
    problems.check()
    # Channels: the legacy form's sensors ascending, otherwise in the order of their first row.
    channel_keys = sorted(set(keys)) if legacy else list(dict.fromkeys(keys))
    channel_of = {key: c for c, key in enumerate(channel_keys)}
    channel = np.array([channel_of[k] for k in keys])
    _, channel_first = np.unique(channel, return_index=True)
    n = len(channel_keys)
    channel_kind = []
    for c, i0 in enumerate(channel_first):
        mine = np.flatnonzero(channel == c)
        other = mine[kinds[mine] != kinds[i0]]
        if other.size:
            problems.add(f"{where[i0]} and {where[other[0]]}: {_describe_key(channel_keys[c])} is given as "
                         f"{kinds[i0]} and as {kinds[other[0]]}; one kind per channel")
        channel_kind.append(str(kinds[i0]))
        if averages is not None and np.any(averages[mine] != averages[i0]):
            j = mine[averages[mine] != averages[i0]][0]
            problems.add(f"{where[i0]} and {where[j]}: {_describe_key(channel_keys[c])} has {averages[i0]:g} and "
                         f"{averages[j]:g} averages; one number per channel")
        if units is not None and np.any(units[mine] != units[i0]):
            j = mine[units[mine] != units[i0]][0]
            problems.add(f"{where[i0]} and {where[j]}: {_describe_key(channel_keys[c])} is given in {units[i0]} "
                         f"and in {units[j]}; one unit per channel")
    problems.check()

    # Drop the 0 Hz lines (mobility, accelerance), then check the grid.
    notes = list(file_notes)
    if zero.any():
        dropped = sorted({channel_keys[c] for c in channel[zero]}, key=channel_keys.index)
        what = sorted({str(k) for k in kinds[zero]})
        notes.append(f"dropped the 0 Hz line of {len(dropped)} channel(s) ({', '.join(what)} is 0 there by "
                     "definition; the FE model needs f > 0)")
    keep = ~zero
    frequencies = np.unique(frequency[keep])
    if frequencies.size == 0:
        raise MeasuredDataError(f"{source}: no data rows above 0 Hz")
    line = np.searchsorted(frequencies, frequency)
    present = np.zeros((frequencies.size, n), dtype=bool)
    present[line[keep], channel[keep]] = True
    if not present.all():
        c_i, f_i = np.argwhere(~present.T)[0]
        missing = int((~present).sum())
        raise MeasuredDataError(
            f"{source}: incomplete grid: {_describe_key(channel_keys[c_i])} has no row at frequency_hz"
            f" {frequencies[f_i].item()!r} ({missing} of {n} x {frequencies.size} missing)"
        )
    shape = (frequencies.size, n)
    amp = np.empty(shape)
    amp[line[keep], channel[keep]] = amplitude[keep]
    cplx = None
    if complex_data is not None:
        cplx = np.empty(shape, dtype=complex)
        cplx[line[keep], channel[keep]] = complex_data[keep]
    coh = None
    if coherence is not None:
        coh = np.empty(shape)
        coh[line[keep], channel[keep]] = coherence[keep]
    converted = {}
    for c, kind in enumerate(channel_kind):
        if kind != "receptance":
            converted.setdefault(kind, []).append(c)
            amp[:, c] = to_receptance(amp[:, c], frequencies, kind)
            if cplx is not None:
                cplx[:, c] = to_receptance(cplx[:, c], frequencies, kind)
    for kind, cols in converted.items():
        notes.append(f"converted {len(cols)} channel(s) from {kind} to receptance (divided by "
                     f"{'j 2 pi f' if kind == 'mobility' else '-(2 pi f)^2'}"
                     f"{'' if cplx is not None else ', in modulus'})")
    line_first = {}
    for i in np.flatnonzero(keep):
        line_first.setdefault(int(line[i]), i)
    return MeasuredFRF(
        frequencies_hz=frequencies,
        sensors=np.array([k[0] for k in channel_keys]) if legacy else np.arange(1, n + 1),
        amplitude=amp,
        complex_frf=cplx,
        source=source,
        responses=None if legacy else tuple(k[0] for k in channel_keys),
        references=None if legacy else tuple(k[1] for k in channel_keys),
        coherence=coh,
        kinds=None if all(k == "receptance" for k in channel_kind) else tuple(channel_kind),
        places=tuple(where[i] for i in channel_first),
        line_places=tuple(where[line_first[k]] for k in range(frequencies.size)),
        notes=tuple(notes),
        units=None if units is None else tuple(str(units[i]) for i in channel_first),
        averages=None if averages is None else averages[channel_first].astype(np.int64),
    )


def _describe_key(key) -> str:
    if len(key) == 1:
        return f"sensor {key[0]}"
    response, reference = key
    if reference is None:
        return f"response {response!r} (default excitation)"
    return f"response {response!r}, reference {reference!r}"
