"""Writing a study's report directory.

``write_report(result, directory)`` writes, each file atomically:

* ``report.html`` - the page (CSS and JavaScript inline, the figures embedded;
  works offline, from ``file://``): a table of contents, what was measured and
  how time was taken, the slope / efficiency tables, plots, per scene an
  interactive image viewer (:mod:`mcrt.analysis.viewer`: samplers, sample
  counts, the reference and five error views at native resolution, zoom, pan,
  exposure, a pixel readout, crops of the hardest regions), and the full table
  of cells; every table sorts by a click on its header;
* ``viewer/<scene>/*.js`` - the viewer's images (float16, deflated; loaded by
  the page only when shown, :mod:`mcrt.analysis.viewer.data`);
* ``exr/<scene>/*.exr`` - the reference (with its standard error) and, per
  cell, the mean over seeds (with its per-pixel variance) and the first seed's
  render, float32, each header recording how it was made
  (:mod:`mcrt.analysis.viewer.files`), linked from the viewer;
* ``summary.png`` - the main figure: excess MSE against spp per scene (the
  headline; time is the noisy axis), over the error maps of every sampler on
  the first scene;
* ``error_vs_spp.png`` and ``error_vs_time.png`` - log-log excess MSE against
  samples per pixel and against seconds, one panel per scene, one line per
  sampler with its fitted slope (the cost curve of accuracy);
* ``images_<scene>.png`` - the image grid of each scene;
* ``results.csv`` - one row per (scene, sampler, spp) cell (means over seeds
  and their spread; the study's command on every row);
* ``results.json`` - the configuration, environment, references, every cell
  with its per-seed values, and the fits (NaN written as ``null``).

The columns of results.csv, the cells' keys, the definitions and the columns
of the report's tables all derive from the declaration of a cell's fields,
:mod:`mcrt.analysis.study.fields`; the figures are drawn by
:mod:`mcrt.analysis.study.figures`.

A partial result (an interrupted study, :attr:`StudyResult.partial`) is written
the same way and marked in every file: ``"partial": true`` and a ``progress``
record (cells done / total, the interrupted cell and its seeds done, the
pending cells, how to resume) in results.json; a ``status`` column (done /
interrupted / pending) with ``seeds_done`` in results.csv, pending cells as
rows with empty values; a banner in report.html. Plots and slopes use the
finished cells only.
"""

from __future__ import annotations

import base64
import csv
import html
import math
import os
from pathlib import Path
from typing import Any

from ..core.atomic import atomic_path, ensure_writable_dir
from ..core.jsonfile import json_safe, write_json
from ..core.provenance import COMMAND, csv_values, html_note, png_text
from .plots import save_figure
from .report_tables import (
    cell_header,
    cell_rows,
    findings_banners,
    fmt,
    partial_banner,
    summary_header,
    summary_rows,
    table,
)
from .study import RESOLVED_FACTOR, StudyResult, cell_keys
from .study.conclude import cpus_line
from .study.fields import CSV_COLUMNS, DEFINITIONS
from .study.figures import error_figure, images_figure, summary_figure
from .viewer import HELP, viewer_assets, viewer_sections
from .viewer.data import write_viewer_data
from .viewer.files import write_exrs

TIME_NOTE = (
    "Time is the wall time of one render (render_film: tracing every pass, accumulating and "
    "developing the film, synchronised with dr.sync_thread()), taken by one protocol "
    "(mcrt.core.timing): every sampler at one sample count is one group; each cell first "
    "renders once untimed (a warm-up that compiles or loads every kernel), then the group's "
    "timed renders come in rounds, each rendering every cell once in an order shuffled per "
    "round, so that a change of machine load hits every sampler alike. The first rounds "
    "render the seeds (scored), the rest are timing-only renders. A cell's time is the median "
    "of its rounds with a 95% interval; process CPU time and the other processes runnable "
    "at each render's start are recorded too. Ratios to the baseline pair the renders of "
    "one round. Scene loading, sampler construction, copying the image to NumPy and the "
    "metrics are not included; the reference's render time is reported separately.")


def time_note(environment: dict[str, Any]) -> str:
    """The report's note on time: :data:`TIME_NOTE`, and where the study could use
    fewer CPUs than its machine has, that its absolute times hold for those."""
    pinned = cpus_line(environment)
    return f"{TIME_NOTE} Note: {pinned}." if pinned else TIME_NOTE


# --------------------------------------------------------------------------- data files


def results_json(result: StudyResult) -> dict[str, Any]:
    """Everything a study measured, as JSON-ready data."""
    return json_safe({
        "partial": result.partial,
        "command": result.command,
        "progress": result.progress(),
        "study": result.config.as_dict(),
        "environment": result.environment,
        "seconds_total": result.seconds,
        "time_note": TIME_NOTE,
        "time_protocol": result.timing,
        "biased_cells": [{"scene": c["scene"], "sampler": c["sampler"], "spp": c["spp"],
                          "bias": c["bias"], "bias_z": c["bias_z"]} for c in result.biased],
        "definitions": DEFINITIONS,
        "references": {name: vars(info) for name, info in result.references.items()},
        "effective_spp": [{"sampler": label, "spp_requested": spp, "spp": eff}
                          for (label, spp), eff in result.config.effective_spp.items()],
        "cells": result.cells,
        "fits": result.fits,
    })


def _csv_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else "nan"
    if isinstance(value, dict):
        return ";".join(f"{k}={v}" for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return " ".join(str(v) for v in value)
    return str(value)


def csv_rows(result: StudyResult) -> list[list[str]]:
    """Rows of results.csv: every cell of the study in order; a cell not (yet)
    measured has status ``pending`` (or ``interrupted``) and empty values."""
    k = len(result.config.seeds)
    stop = result.interrupted or {}
    plugin = {s.label: s for s in result.config.samplers}
    rows: list[dict[str, Any]] = [
        {**cell, "status": "done", "seeds_done": len(cell["seeds"]), "seeds_total": k}
        for cell in result.cells]
    for scene, label, spp in result.pending():
        running = (stop.get("scene"), stop.get("sampler"), stop.get("spp")) == (scene, label, spp)
        rows.append({"scene": scene, "sampler": label, "plugin": plugin[label].name,
                     "params": dict(plugin[label].params), "spp_requested": spp,
                     "status": "interrupted" if running else "pending",
                     "seeds_done": stop.get("seeds_done", 0) if running else 0,
                     "seeds_total": k})
    if result.partial:  # study order, done cells first would mislead: sort like the config
        order = {key: i for i, key in enumerate(cell_keys(result.config))}
        rows.sort(key=lambda r: order[(r["scene"], r["sampler"], r["spp_requested"])])
    made = csv_values({COMMAND: result.command})  # how the file was made: on every row
    return [[_csv_value(row[c]) if c in row else "" for c in CSV_COLUMNS]
            for row in ({**r, **made} for r in rows)]


def write_results_csv(result: StudyResult, path: str | os.PathLike[str]) -> None:
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(CSV_COLUMNS)
        writer.writerows(csv_rows(result))


def write_results_json(result: StudyResult, path: str | os.PathLike[str]) -> None:
    write_json(path, results_json(result), indent=1)


# --------------------------------------------------------------------------- HTML


def _png_data(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em;
color:#222;max-width:1400px}
h1{font-size:1.6em}h2{font-size:1.25em;margin-top:1.8em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:12px;margin:0.6em 0}
th,td{border:1px solid #ccc;padding:3px 6px;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}
table.cells td:nth-child(2){text-align:left}
img{max-width:100%}.note{color:#555;font-size:13px;max-width:60em}
.partial{background:#fff3cd;border:2px solid #d39e00;padding:0.6em 1em;max-width:60em}
dl{font-size:13px}dt{font-weight:600;margin-top:0.4em}dd{margin-left:1.5em}
code{background:#f6f6f6;padding:0 3px}
"""


def render_html(result: StudyResult, files: dict[str, Path],
                viewer_data: dict[str, dict[str, Any]] | None = None) -> str:
    """The report page; ``files``: the figures written (see :func:`report_files`),
    ``viewer_data``: every scene's viewer data, its images written beside the page
    (:func:`~mcrt.analysis.viewer.data.write_viewer_data`; without it, no viewers)."""
    parts = (_html_intro(result, files) + _html_convergence(result, files)
             + _html_images(result, files, viewer_data or {}) + _html_references(result)
             + _html_cells(result) + _html_definitions())
    return "\n".join(parts)


#: The report's sections: (id, title), in order (the table of contents).
SECTIONS = (("summary", "Summary"), ("convergence", "Convergence and efficiency"),
            ("images", "Images"), ("references", "References"), ("cells", "All cells"),
            ("definitions", "Definitions"))


def _toc(result: StudyResult) -> str:
    items = []
    for key, title in SECTIONS:
        sub = ""
        if key == "images":
            sub = "<ul>" + "".join(f"<li><a href='#viewer-{i}'>{html.escape(s)}</a></li>"
                                   for i, s in enumerate(result.scenes)) + "</ul>"
        items.append(f"<li><a href='#{key}'>{title}</a>{sub}</li>")
    return f"<nav class='toc'><b>Contents</b><ul>{''.join(items)}</ul></nav>"


def _h2(key: str) -> str:
    return f"<h2 id='{key}'>{dict(SECTIONS)[key]}</h2>"


def _html_intro(result: StudyResult, files: dict[str, Path]) -> list[str]:
    """Head, title, banner, what ran where, the time note and the summary figure."""
    config = result.config
    env = result.environment
    mark = " (partial)" if result.partial else ""
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
             f"<title>mcrt study: {html.escape(config.name)}{mark}</title>"
             f"<style>{_CSS}{viewer_assets()[0]}</style></head><body>",
             f"<h1>mcrt study: {html.escape(config.name)}{mark}</h1>"]
    if result.partial:
        parts.append(partial_banner(result))
    parts += findings_banners(result)
    if config.description:
        parts.append(f"<p>{html.escape(config.description)}</p>")
    parts.append(
        f"<p class='note'>{len(config.scenes)} scene(s) &times; {len(config.samplers)} "
        f"sampler(s) &times; spp {', '.join(map(str, config.spp))} &times; "
        f"{len(config.seeds)} seeds; reference: {html.escape(config.reference.sampler_text())}, "
        f"{config.reference.spp} spp. Ran {result.seconds:.0f} s on "
        f"{html.escape(str(env['platform']))}, "
        f"{env['cpus']} CPUs, Mitsuba {env['mitsuba']}, Dr.Jit {env['drjit']}, "
        f"{html.escape(env['variant'])}, mcrt {env['mcrt']}, started {env['started']}.</p>")
    parts.append(html_note({COMMAND: result.command}))
    if result.resumed_cells and not result.partial:
        parts.append(f"<p class='note'>{result.resumed_cells} of {config.cells} cells were "
                     "measured by an earlier, interrupted run and taken from its saved state "
                     "(same configuration, scenes and versions); their times were taken then."
                     "</p>")
    parts.append(f"<p class='note'><b>Time.</b> {html.escape(time_note(env))}</p>")
    parts += [_toc(result), _h2("summary")]
    if "summary" in files:
        parts.append(f"<p><img alt='summary' src='{_png_data(files['summary'])}'></p>")
    return parts


def _html_convergence(result: StudyResult, files: dict[str, Path]) -> list[str]:
    """Slopes and efficiencies per scene, and the error plots."""
    parts = [_h2("convergence"),
             "<p class='note'>Slopes are least-squares fits of log MSE (reference noise "
             "removed) against log spp and against log seconds, over every seed of the "
             "resolved cells, with 95% intervals. Efficiency is "
             "1&nbsp;/&nbsp;(MSE &times; seconds) on the median wall time of a render: "
             "higher is better; a sampler twice as efficient reaches the same error in half "
             "the time. The table gives each sampler's efficiency as a ratio to the baseline "
             f"<b>{html.escape(result.config.baseline)}</b> at the same spp, with its 95% "
             "interval (<i>n.s.</i>: the interval contains 1, no significant difference), "
             "and its cost per render split into a fixed part and a part per sample (a "
             "least-squares line over every timed render). In the plots the vertical bars "
             "are the 95% interval of the mean excess MSE over seeds (as in the "
             "efficiency's) and the horizontal bars that of the median render time; on the "
             "time plot grey "
             "labels give the sample count, a hollow marker a cell whose timing was "
             "disturbed and a red ring a significant bias; a cross marks an "
             f"<i>unresolved</i> cell: its MSE is below {RESOLVED_FACTOR:g}&times; the "
             "reference's own noise floor (dotted line), so the reference cannot tell its "
             "error apart from zero; it is left out of the fits.</p>"]
    for scene in result.scenes:
        parts.append(f"<h3>{html.escape(scene)}</h3>")
        parts.append(table(summary_header(result), summary_rows(result, scene)))
    for key, alt in (("error_vs_spp", "error vs spp"), ("error_vs_time", "error vs time")):
        if key in files:
            parts.append(f"<p><img alt='{alt}' src='{_png_data(files[key])}'></p>")
    return parts


def _html_images(result: StudyResult, files: dict[str, Path],
                 viewer_data: dict[str, dict[str, Any]]) -> list[str]:
    """The image viewer of every scene."""
    config = result.config
    sheets = ", ".join(f"<code>{html.escape(p.name)}</code>" for k, p in files.items()
                       if k.startswith("images_"))
    parts = [_h2("images"),
             "<p class='note'>Per scene, every sampler at every sample count, the first seed "
             f"({config.seeds[0]}) or the mean of the {len(config.seeds)} seeds, against the "
             "reference: each pixel shown as a block of whole screen pixels, never resampled. "
             "Error views are of luminance against the reference: signed (red: too bright, "
             "blue: too dark), absolute, relative (|error| / sqrt(reference&sup2; + 0.01)), "
             "FLIP (perceptual, 0-1, of the first seed) and the per-pixel variance across "
             "seeds (zero where a sampler is deterministic, e.g. the uniform grid: its error "
             "is all bias). One colour scale per view and sample count, shared by the "
             "samplers (the 99th percentile; { and } halve or double it). The viewers show "
             "float16 copies of the images (11 significant bits), each loaded from "
             "<code>viewer/</code> when shown; the EXR files linked under each viewer hold "
             "them in float32.</p>",
             f"<p class='note'>{HELP}</p>"]
    if sheets:
        parts.append(f"<p class='note'>Static sheets at {config.image_spp} spp: {sheets}.</p>")
    parts += viewer_sections(result, viewer_data)
    return parts


def _html_references(result: StudyResult) -> list[str]:
    rows = [[html.escape(r.scene), f"{r.width}x{r.height}", str(r.spp), html.escape(r.sampler),
             fmt(r.seconds) + (" (cached)" if r.cached else ""), fmt(r.noise_floor),
             fmt(r.rel_noise_floor)]
            for r in result.references.values()]
    return [_h2("references"),
            table(["scene", "pixels", "spp", "sampler", "seconds", "MSE floor",
                    "relMSE floor"], rows)]


def _html_cells(result: StudyResult) -> list[str]:
    return [_h2("cells") + "<p class='note'>Means over seeds &plusmn; sample standard "
            "deviation. Unresolved cells (MSE below "
            f"{RESOLVED_FACTOR:g}&times; the reference's noise floor) are marked "
            "and excluded from fits.</p>",
            table(cell_header(), cell_rows(result), cls="cells")]


def _html_definitions() -> list[str]:
    parts = [_h2("definitions") + "<dl>"]
    for key, text in DEFINITIONS.items():
        parts.append(f"<dt><code>{html.escape(key)}</code></dt><dd>{html.escape(text)}</dd>")
    parts.append("</dl><p class='note'>Data: <code>results.csv</code> (one row per cell), "
                 "<code>results.json</code> (everything, with per-seed values); plots: "
                 "<code>error_vs_spp.png</code>, <code>error_vs_time.png</code>.</p>")
    parts.append(f"<script>{viewer_assets()[1]}</script></body></html>\n")
    return parts


def report_files(directory: str | os.PathLike, scenes: list[str]) -> dict[str, Path]:
    """The files :func:`write_report` writes into ``directory``, by role."""
    directory = Path(directory)
    files = {"report": directory / "report.html", "csv": directory / "results.csv",
             "json": directory / "results.json",
             "summary": directory / "summary.png",
             "error_vs_spp": directory / "error_vs_spp.png",
             "error_vs_time": directory / "error_vs_time.png"}
    for scene in scenes:
        files[f"images_{scene}"] = directory / f"images_{scene}.png"
    return files


def write_report(result: StudyResult, directory: str | os.PathLike) -> dict[str, Path]:
    """Write every report file into ``directory`` (created if needed); returns them."""

    ensure_writable_dir(Path(directory))
    files = report_files(directory, [s.name for s in result.config.scenes])
    write_results_csv(result, files["csv"])
    write_results_json(result, files["json"])
    text = png_text({"command": result.command} if result.command else {})
    if result.scenes:
        for axis, key in (("spp", "error_vs_spp"), ("seconds", "error_vs_time")):
            save_figure(error_figure(result, axis), files[key], dpi=110, text=text)
        save_figure(summary_figure(result), files["summary"], dpi=100, text=text)
    else:  # interrupted before the first reference: nothing to plot
        for key in ("error_vs_spp", "error_vs_time", "summary"):
            files.pop(key)
    for scene in result.config.scenes:
        if any(s == scene.name for s, _ in result.images):
            save_figure(images_figure(result, scene.name), files[f"images_{scene.name}"],
                        dpi=110, text=text)
        else:
            files.pop(f"images_{scene.name}")
    links = write_exrs(result, directory)
    viewer_data = write_viewer_data(result, directory, links)
    html = render_html(result, files, viewer_data)
    with atomic_path(files["report"]) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(html)
    return files


__all__ = ["CSV_COLUMNS", "DEFINITIONS", "TIME_NOTE", "cell_header", "cell_rows", "csv_rows",
           "partial_banner", "render_html", "report_files", "results_json", "summary_header",
           "summary_rows", "time_note", "write_report", "write_results_csv",
           "write_results_json"]
