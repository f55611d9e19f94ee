"""The modal run's report: ``report.html`` in the run folder, from ``summary.json`` and the pictures the run
wrote (MAC before and after, the paired shapes on the mesh). Plain HTML, pictures linked, nothing fetched."""

from __future__ import annotations

import html
from pathlib import Path

__all__ = ["write_report"]


def _table(header: list[str], rows: list[list]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _closure(c: dict | None) -> str:
    """The closure's section: its verdict, the tests before and after, the best candidates."""
    if c is None:
        return ""
    before = c["before"]
    text = (f"<h2>Closure on the modal residual: {html.escape(c['verdict'])}</h2><p>after the update chi-square "
            f"{before['chi2']:.1f} for {before['dof']} degrees of freedom (p = {before['p_value']:.3g}; "
            f"{'structure' if before['structured'] else 'noise'} at the {c['level']} level, uncertainties "
            f"{html.escape(c['uncertainties'])}); {c['n_screened']} candidates screened "
            f"({html.escape(', '.join(c['effects']))}), {c['fe_runs']} FE runs.</p>")
    if c["chosen"] is not None:
        after = c["after"]
        added = c.get("added") or [c["chosen"]]
        text += (f"<p>Added (forward selection, values of the last joint fit): "
                 + "; ".join(f"{html.escape(ch['effect'])} at {html.escape(ch['location'])}, {ch['value']:.4g} "
                             f"{html.escape(ch['unit'])} (sd {ch['sd']:.2g})" for ch in added)
                 + f": chi-square {after['chi2']:.1f} for {after['dof']} degrees of freedom "
                 f"(p = {after['p_value']:.3g}).</p>")
    rows = [[x["effect"], x["location"], "" if x.get("position_m") is None else
             ", ".join(f"{1000 * v:.1f}" for v in x["position_m"]), f"{x['value']:.4g} {x['unit']}",
             f"{x['linear_drop']:.1f}", "" if x.get("chi2") is None else f"{x['chi2']:.1f}"]
            for x in c["candidates"]]
    return text + _table(["effect", "location", "x, y, z mm", "value", "linearised chi2 drop", "chi2 checked"], rows)


def write_report(folder: Path, summary: dict) -> Path:
    """Write ``<folder>/report.html``; returns its path."""
    folder = Path(folder)
    inside, iv = summary.get("intervals_contain_truth"), summary["intervals"]
    params = [[n, f"{v:+.4f}", f"{iv[n]['sd']:.4f}", f"[{iv[n]['lower95']:+.4f}, {iv[n]['upper95']:+.4f}]"]
              + ([("inside" if inside[n] else "OUTSIDE")] if inside is not None else [])
              for n, v in summary["parameters"].items()]
    pairs = [[p["test"], f"{p['f_test_hz']:.3f}", p["model"], f"{p['f_model_hz']:.3f}",
              f"{100 * (p['f_model_hz'] - p['f_test_hz']) / p['f_test_hz']:+.3f}", f"{p['mac']:.3f}"]
             for p in summary["paired_modes"]]
    lines = [f"{summary['fe_evaluations']} FE runs ({summary['jacobians']} with Nelson derivatives), "
             f"{summary['seconds']:.1f} s; chi-square {summary['chi2']:.1f} for {summary['n_residuals']} residuals, "
             f"uncertainties {summary['uncertainties']} (sigma_f {summary['sigma_f']}, sigma_s {summary['sigma_s']})"]
    if "paper_loop" in summary:
        pl = summary["paper_loop"]
        lines.append(f"paper loop (MRGP over the modal residuals): {pl['reason']}; {pl['iterations']} iterations, "
                     f"{pl['fe_runs']} FE runs, {pl['seconds']:.1f} s, best mean |r| {pl['best_error']:.3f} "
                     f"(noise threshold {pl['threshold']:.3f}); then the local fit from its best FE run")
    for key, label in (("missing_mode_numbers", "missing from the measured modes"),
                       ("left_out", "left out (unpaired at the nominal model)"), ("mode_swaps", "mode swaps tracked")):
        if summary.get(key):
            lines.append(f"{label}: {'; '.join(summary[key])}")
    lines += summary.get("notes", [])
    pictures = "".join(f'<h2>{html.escape(title)}</h2><img src="{name}" alt="{name}">'
                       for name, title in (("mac_before.png", "MAC before the update"),
                                           ("mac_after.png", "MAC after the update"),
                                           ("shapes_after.png", "Paired shapes on the mesh, after the update"))
                       if (folder / name).exists())
    text = (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(summary['run_id'])}</title>"
            "<style>body{font-family:sans-serif;max-width:60em} td,th{padding:2px 8px;text-align:right}"
            "img{max-width:100%}</style></head><body>"
            f"<h1>Modal update {html.escape(summary['run_id'])}</h1>"
            f"<p>model {html.escape(str(summary['model']))}, measured {html.escape(str(summary['measured']))}</p>"
            + "".join(f"<p>{html.escape(line)}</p>" for line in lines)
            + "<h2>Parameters (95 % intervals)</h2>"
            + _table(["parameter", "value", "sd", "95 %"] + (["truth"] if inside is not None else []), params)
            + "<h2>Paired modes</h2>"
            + _table(["measured", "f Hz", "model", "f Hz", "difference %", "MAC"], pairs)
            + f"<p>Residual: {html.escape(summary['residual'])}</p>" + _closure(summary.get("closure"))
            + pictures + "</body></html>\n")
    path = folder / "report.html"
    path.write_text(text)
    return path
