"""What enters an update: measured channels matched to the model, the selected lines, the residual.

:func:`update_data` takes the measured FRFs (:mod:`tasks.io.measured`) and the
FE model and returns an :class:`UpdateData`:

Channels
    A response label is a sensor name of the model file or ``NODE:DIR``,
    matched to the sensor whose ``test_node`` is NODE and whose test
    direction is +-DIR; a reference label likewise among the excitations;
    no reference means the model's default excitation (its ``excitation``
    key). Direction rule: the sign applied to a measured FRF is the
    product of the signs of the file's direction code and of the model
    file's ``test_direction`` (what the test calls the model's DOF), so
    ``-z`` in the file against ``+z`` in the model flips the sign, and a
    negative code in the file against a negative ``test_direction`` flips
    it twice (no flip): that combination is a warning naming the channels
    (logged, printed, in the manifest's ``direction_warnings``), since it
    usually is one upside-down sensor declared in both places. The legacy form (sensor numbers) is the
    model's sensors under its default excitation. Refusals
    (:class:`MeasuredDataError`) name the file and the line of the channel.
Lines
    :func:`tasks.lines.select_lines` (config keys ``lines``, ``line_windows``,
    ``resonance_widen``, ``min_coherence``).
Residual
    ``residuals = "amplitude"``: Eq. (5), ``|Z| / u - 1``; ``"complex"``:
    the real and imaginary parts of ``(Z - H) / |H|``
    (:class:`fe_core.inference.frf_data.FRFData`, which computes every residual), k doubles;
    ``"auto"``: complex when the data carry phase, except the legacy form,
    which keeps the paper's amplitude residual (its ``real``/``imag``
    columns were optional extras, and the benchmark's results stay as they
    were). The overall error is Eq. (6b) of the residual vector either way.

The residual vector holds the kept (line, channel) values frequency-major,
channels fastest (the layout of Eq. 5); with complex residuals first all real
parts, then all imaginary parts.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np

from fe_core.inference.frf_data import FRFData
from tasks.io.measured import MeasuredDataError, MeasuredFRF, dof_label, parse_dof
from tasks.io.measured.frf import POWER
from tasks.io.measured.problems import Problems
from tasks.lines import select_lines

__all__ = ["UpdateData", "update_data", "RESIDUALS", "resolve_channels"]

log = logging.getLogger(__name__)

RESIDUALS = ("auto", "amplitude", "complex")
_AXES = "xyz"


@dataclass(frozen=True, eq=False)
class UpdateData(FRFData):
    """The measured values an update fits, matched to the model: :class:`fe_core.inference.frf_data.FRFData`
    (the values, which are kept, every residual) with where they came from.

    Attributes (besides FRFData's ``frequencies_hz``, ``amplitude``, ``complex_frf``, ``mask``, ``residual``)
    ----------
    measured : MeasuredFRF
        As read (every line).
    responses, references : ndarray of int, shape (n,), or None
        Model sensor and excitation (0-based) of each channel; None when the
        channels are the model's sensors in order under its default
        excitation (then :meth:`fe_core.model.ParametricModel.frf` is used).
    selection : dict
        What was selected and dropped, for the manifest and the report.
    channel_info : list of dict
        Per channel: label, response, reference, sensor, excitation, sign, kind, place.
    """

    measured: MeasuredFRF | None = None
    responses: np.ndarray | None = None
    references: np.ndarray | None = None
    selection: dict = field(default_factory=dict)
    channel_info: list = field(default_factory=list)

    # -- what the rest of the flow reads like a MeasuredFRF --------------------------------------
    @property
    def source(self) -> str:
        return self.measured.source

    @property
    def sensors(self) -> np.ndarray:
        """Channel numbers (the legacy form's sensor numbers)."""
        return self.measured.sensors

    @property
    def channels(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(responses, references)`` for :func:`tasks.fe_runs.evaluate_sample`, or None (the model's FRF)."""
        return None if self.responses is None else (self.responses, self.references)

    def line_place(self, i: int) -> str:
        """Where selected line ``i`` first appears in the file."""
        full = np.flatnonzero(self.selection_lines)[i]
        return self.measured.line_places[full] if self.measured.line_places else f"line {full + 1}"

    @property
    def selection_lines(self) -> np.ndarray:
        return np.asarray(self.selection["line_mask"], dtype=bool)

    def residual_columns(self, Z: np.ndarray) -> dict:
        """Long residual rows of one FE run ``Z`` (p, n): the kept values, frequency-major.

        ``frequency_hz``, ``sensor`` (channel number), ``residual`` (the
        amplitude residual of Eq. 5, also with complex residuals) and, with
        complex residuals, ``residual_real``, ``residual_imag``.
        """
        line, channel = self.cells
        z = self.kept(Z)
        out = {"frequency_hz": self.frequencies_hz[line], "sensor": self.sensors[channel].astype(np.int64),
               "residual": self.amplitude_residual(z)}
        if self.complex:
            r = self(z)
            out.update(residual_real=r[: line.size], residual_imag=r[line.size:])
        return out

    # -- views for stages that need one load and a full grid ----------------------------------------
    def single_reference_model(self, model):
        """The model seen through the channels: their sensors as outputs, their one reference as the load.

        Its ``frf`` gives the channels' receptance, so stages written for the
        model's FRF (intervals, closure) work on the data. Raises ValueError
        with several references (MIMO).
        """
        if self.responses is None:
            return model
        refs = np.unique(self.references)
        if refs.size != 1:
            names = ", ".join(model.excitation_names[r] for r in refs)
            raise ValueError(f"{self.source}: the channels have {refs.size} references ({names}); this needs one")
        return dataclasses.replace(
            model, outputs=model.outputs[:, self.responses], load=model.excitation_loads[:, refs[0]].copy(),
            sensor_names=[model.sensor_names[s] for s in self.responses],
            excitation_name=model.excitation_names[refs[0]],
            sensor_test_dofs=[model.sensor_test_dofs[s] for s in self.responses],
        )

    def manifest_entry(self) -> dict:
        """What was read, converted, matched and selected (``manifest.json``'s ``measured_data``)."""
        sel = {k: v for k, v in self.selection.items() if k != "line_mask"}
        return {"source": self.source, "form": "legacy (sensor numbers, default excitation)" if self.measured.legacy
                else "channels (response, reference)", "residual": self.residual, "values": self.n_values,
                "complex": self.measured.complex_frf is not None,
                "coherence": self.measured.coherence is not None, "notes": list(self.measured.notes),
                "direction_warnings": [c["label"] for c in self.channel_info if c.get("double_flip")],
                "channels": self.channel_info, "selection": sel,
                "noise": None if self.noise is None else self.noise.to_dict()}

    def describe(self) -> list[str]:
        """Log lines: conversions, channels, selection, residual."""
        s = self.selection
        out = [f"{self.source}: {note}" for note in self.measured.notes]
        refs = sorted({c["excitation"] for c in self.channel_info})
        out.append(f"{self.source}: {self.n_channels} channels, reference(s) {', '.join(refs)}")
        flipped = [c["label"] for c in self.channel_info if c["sign"] < 0]
        if flipped:
            out.append(f"{self.source}: sign flipped (direction opposite to the model's) for {', '.join(flipped)}")
        twice = [c["label"] for c in self.channel_info if c.get("double_flip")]
        if twice:
            out.append(f"WARNING: {self.source}: the file's direction and the model file's test_direction are both "
                       f"negative for {', '.join(twice)}: the flips cancel (sign +1, data used as measured); an "
                       "upside-down sensor is declared in one place only (see docs/guide/measured-data.md)")
        windows = ", ".join(f"{lo:.4g}-{hi:.4g} Hz" for lo, hi in s["windows"])
        empty = f" ({s['lines_dropped']} lines left empty)" if s["lines_dropped"] else ""
        out.append(f"lines: {s['mode']}{' (' + windows + ')' if windows else ''}: {s['lines_selected']} of "
                   f"{s['lines_in_file']} lines; coherence below {s['min_coherence']:g}: {s['coherence_dropped']} "
                   f"of {s['values_in_windows']} values dropped{empty}")
        out.append(f"residual: {self.residual}, k = {self.n_values} values")
        if self.noise is not None:
            avg = sorted({int(a) for a in np.atleast_1d(self.measured.averages)})
            out.append(f"noise: {self.noise.describe()} ({', '.join(map(str, avg))} averages)")
        else:
            out.append("noise: no coherence with its number of averages: a relative term and a floor per channel "
                       "estimated from the residual wherever it is tested (or --noise)")
        return out


def _match(label: str, names: list[str], tests: list, what: str, table: str, source: str, place: str):
    """(index, sign) of a label among a model's sensors or excitations."""
    try:
        dof = parse_dof(label)
    except ValueError as exc:
        raise MeasuredDataError(f"{source}: {place}: {what} {exc}") from None
    if dof is None:
        if label not in names:
            raise MeasuredDataError(f"{source}: {place}: unknown {what} {label!r}: the model's {table} are "
                                    f"{', '.join(map(repr, names))}")
        return names.index(label), 1
    node, direction = dof
    here = [(k, t) for k, t in enumerate(tests) if t is not None and t[0] == node]
    if not here:
        known = sorted({t[0] for t in tests if t is not None})
        raise MeasuredDataError(f"{source}: {place}: unknown {what} {label!r}: no {table[:-1]} has test_node = {node} "
                                f"(test nodes of the model's {table}: {known or 'none; add test_node keys'})")
    if not 1 <= abs(direction) <= 3:
        kind = "a scalar" if direction == 0 else "a rotation"
        raise MeasuredDataError(f"{source}: {place}: {what} {label!r} is {kind}: the model cannot measure it "
                                f"(its {table} are translations)")
    for k, (_, test_direction) in here:
        if abs(test_direction) == abs(direction):
            return k, int(np.sign(direction) * np.sign(test_direction))
    along = ", ".join(f"{dof_label(*t)} ({names[k]!r})" for k, t in here)
    raise MeasuredDataError(f"{source}: {place}: {what} {label!r}: a direction the model cannot measure; at test "
                            f"node {node} it has {along}; add a [[{table}]] entry with test_node = {node} and "
                            f"test_direction = \"{'+' if direction > 0 else '-'}{_AXES[abs(direction) - 1]}\"")


def _flips_twice(label, test_dof) -> bool:
    """A file direction code < 0 (``101:-z``) matched to a model test_direction < 0 (``"-z"``)."""
    try:
        dof = parse_dof(label) if isinstance(label, str) else None
    except ValueError:
        return False
    return dof is not None and test_dof is not None and dof[1] < 0 and test_dof[1] < 0


def resolve_channels(measured: MeasuredFRF, model) -> tuple[np.ndarray | None, np.ndarray | None, list, np.ndarray]:
    """Match the channels to the model: (responses, references, info, signs); None, None for the legacy form."""
    n = measured.n_channels
    default = model.excitation_names.index(model.excitation_name)
    if measured.legacy:
        info = [{"label": f"sensor {s}", "response": None, "reference": None,
                 "sensor": model.sensor_names[s - 1] if s <= model.n_sensors else None,
                 "excitation": model.excitation_name, "sign": 1, "kind": (measured.kinds or ["receptance"] * n)[j],
                 "unit": (measured.units or [None] * n)[j], "place": measured.place(j)}
                for j, s in enumerate(measured.sensors.tolist())]
        return None, None, info, np.ones(n)
    responses, references, signs, info = [], [], [], []
    problems = Problems(measured.source)  # every channel the model cannot give, in one message
    for j in range(n):
        place = measured.place(j)
        r = e = None
        with problems.collect():
            r, sr = _match(measured.responses[j], model.sensor_names, model.sensor_test_dofs, "response", "sensors",
                           measured.source, place)
        label = measured.references[j]
        with problems.collect():
            e, se = (default, 1) if label is None else _match(label, model.excitation_names,
                                                              model.excitation_test_dofs, "reference",
                                                              "excitations", measured.source, place)
        if r is None or e is None:
            continue
        responses.append(r)
        references.append(e)
        signs.append(sr * se)
        double = [what for what, text, tests, k in (("response", measured.responses[j], model.sensor_test_dofs, r),
                                                     ("reference", label, model.excitation_test_dofs, e))
                  if _flips_twice(text, tests[k])]
        if double:
            log.warning("%s: %s: channel %s: the %s direction is negative in the file and test_direction is "
                        "negative in the model file: the two sign flips cancel (sign %+d); if the sensor was "
                        "mounted upside down, declare it in one place only", measured.source, place,
                        measured.channel_label(j), " and ".join(double), sr * se)
        info.append({"label": measured.channel_label(j), "response": measured.responses[j], "reference": label,
                     "double_flip": double,
                     "sensor": model.sensor_names[r], "excitation": model.excitation_names[e], "sign": sr * se,
                     "kind": (measured.kinds or ["receptance"] * n)[j], "unit": (measured.units or [None] * n)[j],
                     "place": place})
    problems.check()
    seen = {}
    for j, key in enumerate(zip(responses, references)):
        if key in seen:
            problems.add(f"{measured.place(seen[key])} and {measured.place(j)}: channels "
                         f"{measured.channel_label(seen[key])!r} and {measured.channel_label(j)!r} are the same "
                         f"model sensor and excitation ({model.sensor_names[key[0]]}, "
                         f"{model.excitation_names[key[1]]})")
        else:
            seen[key] = j
    problems.check()
    return np.array(responses), np.array(references), info, np.array(signs, float)


def update_data(measured: MeasuredFRF, model, lines: str = "all", line_windows=None, resonance_widen: float = 2.0,
                min_coherence: float = 0.0, residuals: str = "auto") -> UpdateData:
    """Match ``measured`` to ``model``, select the lines and the residual (see the module docstring).

    Raises
    ------
    MeasuredDataError
        A channel the model cannot give (naming the file and its line), or
        no line left after the selection.
    ValueError
        ``residuals = "complex"`` for amplitude-only data, or an unknown option.
    """
    if residuals not in RESIDUALS:
        raise ValueError(f"residuals must be one of {', '.join(RESIDUALS)}, got {residuals!r}")
    if residuals == "complex" and measured.complex_frf is None:
        raise ValueError(f"residuals = 'complex' needs the phase (real and imag), but {measured.source} holds "
                         "amplitudes only")
    responses, references, info, signs = resolve_channels(measured, model)
    if responses is not None and np.array_equal(responses, np.arange(model.n_sensors)) and np.all(
            references == model.excitation_names.index(model.excitation_name)):
        responses = references = None  # the model's own FRF: the legacy path, bit for bit
    mode = residuals if residuals != "auto" else (
        "complex" if measured.complex_frf is not None and not measured.legacy else "amplitude")
    sel = select_lines(measured.frequencies_hz, measured.amplitude, measured.coherence, lines, line_windows,
                       resonance_widen, min_coherence)
    if not sel.lines.any():
        what = {"all": "every line", "windows": f"the windows {sel.windows}",
                "resonances": f"the resonance windows {sel.windows}"}[sel.mode]
        raise MeasuredDataError(f"{measured.source}: no line left to fit: {what} of {measured.frequencies_hz.size} "
                                f"lines, then coherence >= {min_coherence:g}")
    f = measured.frequencies_hz[sel.lines]
    cplx = None
    if measured.complex_frf is not None:
        cplx = measured.complex_frf[sel.lines] * signs
    selection = {
        "mode": sel.mode, "windows": [list(w) for w in sel.windows], "resonances_hz": sel.resonances_hz,
        "widen": resonance_widen if sel.mode == "resonances" else None, "min_coherence": min_coherence,
        "lines_in_file": int(measured.frequencies_hz.size), "lines_selected": int(f.size),
        "values_in_windows": int(sel.mask.size + sel.lines_dropped * measured.n_channels),
        "coherence_dropped": sel.coherence_dropped, "lines_dropped": sel.lines_dropped,
        "values_kept": int(sel.mask.sum()), "band_hz": [float(f[0]), float(f[-1])],
        "line_mask": sel.lines.tolist(),
    }
    # The noise floor is in the units each channel was measured in (the power of j w from its receptance).
    powers = np.array([POWER.get(c["kind"], 0) for c in info], dtype=int)
    data = UpdateData(measured=measured, frequencies_hz=f, amplitude=measured.amplitude[sel.lines], complex_frf=cplx,
                      native_power=powers, mask=sel.mask, responses=responses, references=references, residual=mode,
                      selection=selection, channel_info=info)
    if measured.coherence is None or measured.averages is None:
        return data
    from fe_core.inference.noise import NoiseModel  # the noise as the measurement states it

    records = any(note.startswith("raw records:") for note in measured.notes)
    with np.errstate(invalid="ignore"):
        noise = NoiseModel.from_coherence(measured.coherence[sel.lines], measured.averages, data.native_amplitude(),
                                          "records" if records else "coherence")
    return dataclasses.replace(data, noise=noise)
