"""The HTML tables of a study's report: the summary per scene and the table of cells,
and the banners over the page (a partial study, biased cells, disturbed timing).

Every column derives from the declaration of the fields
(:mod:`mcrt.analysis.study.fields`): a :class:`~mcrt.analysis.study.fields.Column`
says how its value is shown (text, a value with its sd, se or interval, a z).
:mod:`mcrt.analysis.report` puts the tables in the page.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .aliasing import UNMEASURED
from .study import StudyResult
from .study.conclude import bias_lines, cost_df, cost_text, ratio_parts, timing_lines
from .study.fields import CELL_COLUMNS, FIT_COLUMNS, Cell, Field


def fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if not math.isfinite(value):
            return "&ndash;"
        if value == 0:
            return "0"
        if 1e-3 <= abs(value) < 1e4:
            return f"{value:.{digits}g}"
        return f"{value:.{digits - 1}e}"
    return html.escape(str(value))


def _show(field: Field, record: Mapping[str, Any]) -> str:
    """The HTML of ``field``'s column in a table row of ``record`` (a cell or a
    fit), as its :class:`~mcrt.analysis.study.fields.Column` says."""
    assert field.column is not None
    show, scale = field.column.show, field.column.scale
    name = field.name

    def value(key: str = name) -> Any:
        v = record[key]
        return v * scale if scale != 1 else v

    if show == "text":
        return html.escape(str(record[name]))
    if show == "count":
        return str(record[name])
    if show == "flag":
        return "" if record[name] else html.escape(field.column.false)
    if show in ("sd", "se"):
        return f"{fmt(value())} &plusmn; {fmt(value(f'{name}_{show}'), 2)}"
    if show == "interval" and name == "efficiency_ratio":
        return _ratio(value(), value(f"{name}_low"), value(f"{name}_high"))
    if show == "interval":
        return f"{fmt(value())} [{fmt(value(f'{name}_low'))}, {fmt(value(f'{name}_high'))}]"
    if show == "z":
        return f"{fmt(value())} ({fmt(record[f'{name}_z'], 2)})"
    return fmt(value())


def table(header: list[str], rows: list[list[str]], cls: str = "") -> str:
    cls = f"sortable {cls}".strip()
    head = "".join(f"<th>{h}</th>" for h in header)
    body = "\n".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f'<table class="{cls}"><thead><tr>{head}</tr></thead><tbody>\n{body}\n</tbody></table>'


def _verdicts(cells: Sequence[Cell]) -> str:
    """The verdicts of a sampler's cells in words (aliasing, bias)."""
    aliased = [str(c["spp"]) for c in cells if c["aliasing"] == "aliased"]
    blue = [str(c["spp"]) for c in cells if c["aliasing"] == "blue"]
    biased = [str(c["spp"]) for c in cells if c["biased"]]
    if all(c["aliasing"] == UNMEASURED for c in cells) and not biased:
        return UNMEASURED
    verdict = [f"<b>biased</b> at {', '.join(biased)} spp"] if biased else []
    if aliased:
        verdict.append(f"aliased at {', '.join(aliased)} spp")
    if blue:
        verdict.append(f"blue at {', '.join(blue)} spp")
    return "; ".join(verdict) or "noise"


def summary_header(result: StudyResult) -> list[str]:
    """Header of :func:`summary_rows` (HTML)."""
    return (["sampler"] + [html.escape(f.column.heading) for f in FIT_COLUMNS if f.column]
            + ["fixed ms", "ns / sample"]
            + [f"eff. ratio @{s} [95%]" for s in result.config.spp] + ["verdict"])


def summary_rows(result: StudyResult, scene: str) -> list[list[str]]:
    """Per sampler: slopes and efficiency at every spp (HTML cells)."""
    rows = []
    for sampler in result.config.samplers:
        fit = result.fit(scene, sampler.label)
        cells = [c for c in result.cells if c["scene"] == scene and c["sampler"] == sampler.label]
        by_spp = {c["spp_requested"]: c for c in cells}
        rows.append([html.escape(sampler.label)]
                    + [_show(f, fit) for f in FIT_COLUMNS]
                    + [_cost(fit, "fixed_seconds", 1e3, cells),
                       _cost(fit, "seconds_per_sample", 1e9, cells)]
                    + [_ratio_cell(by_spp[spp]) if spp in by_spp else "pending"
                       for spp in result.config.spp]
                    + [_verdicts(cells)])
    return rows


def _cost(fit: Mapping[str, Any], key: str, scale: float, cells: list[Cell]) -> str:
    """A cost of ``fit`` over ``cells``' timed renders (HTML;
    :func:`~.study.conclude.cost_text`: a bound when the times do not resolve it)."""
    text = cost_text(fit[key], fit[f"{key}_se"], scale, ".3g", df=cost_df(cells))
    return "&ndash;" if text == "-" else html.escape(text)


def _ratio(value: float, low: float, high: float) -> str:
    """An efficiency ratio and its interval (HTML), to the digits the interval's width
    supports (:func:`~.study.conclude.ratio_parts`, as on the console)."""
    if not math.isfinite(value):
        return "&ndash;"
    shown, lower, upper = ("&ndash;" if p == "-" else html.escape(p)
                           for p in ratio_parts(value, low, high))
    return f"{shown} [{lower}, {upper}]"


def _ratio_cell(cell: Cell) -> str:
    """An efficiency ratio with its interval; 'n.s.' when the interval holds 1."""
    if not cell["resolved"]:
        return "unresolved"
    value, low, high = (cell[k] for k in ("efficiency_ratio", "efficiency_ratio_low",
                                          "efficiency_ratio_high"))
    text = _ratio(value, low, high)
    if math.isfinite(low) and low <= 1.0 <= high and low < high:
        text += " <i>n.s.</i>"
    return text


def cell_header() -> list[str]:
    """Header of :func:`cell_rows` (HTML)."""
    return [html.escape(f.column.heading) for f in CELL_COLUMNS if f.column]


def cell_rows(result: StudyResult) -> list[list[str]]:
    """The table of cells (HTML cells): every measured cell, then the pending ones."""
    rows = [[_show(f, c) for f in CELL_COLUMNS] for c in result.cells]
    stop = result.interrupted or {}
    blank = [""] * (len(CELL_COLUMNS) - 4)
    for scene, label, spp in result.pending():  # a partial study: what is missing
        running = (stop.get("scene"), stop.get("sampler"), stop.get("spp")) == (scene, label, spp)
        status = (f"interrupted ({stop['seeds_done']}/{stop['seeds_total']} seeds)" if running
                  else "pending")
        rows.append([html.escape(scene), html.escape(label), f"({spp})", status, *blank])
    return rows


def findings_banners(result: StudyResult) -> list[str]:
    """Banners for what a reader must not miss: biased cells, disturbed timing."""
    out = []
    biased = bias_lines(result.cells)
    if biased:
        items = "".join(f"<li>{html.escape(line)}</li>" for line in biased)
        out.append(f"<div class='partial'><b>Bias found.</b> The mean of these cells' "
                   f"images differs from the reference by more than their noise explains "
                   f"(95% family-wise, over the whole study):<ul>{items}</ul></div>")
    timing = timing_lines(result.timing)
    if timing:
        items = "".join(f"<li>{html.escape(line)}</li>" for line in timing)
        out.append(f"<div class='partial'><b>Timing was doubtful.</b> The cells named "
                   f"have doubtful times and efficiencies:<ul>{items}</ul></div>")
    return out


def partial_banner(result: StudyResult) -> str:
    """The report's notice that the study is incomplete, and how to resume it."""
    total, done = result.config.cells, len(result.cells)
    text = (f"<b>Partial result.</b> The study was interrupted after {done} of {total} "
            f"cells ({len(result.config.seeds)} seeds each)")
    stop = result.interrupted
    if stop:
        text += (f"; the cell being measured ({html.escape(stop['scene'])}, "
                 f"{html.escape(stop['sampler'])}, {stop['spp']} spp) had "
                 f"{stop['seeds_done']} of {stop['seeds_total']} seeds and is not included")
    text += (". Slopes, efficiencies and plots use the finished cells only; the missing "
             "ones are marked <i>pending</i>.")
    if result.resumed_cells:
        text += f" {result.resumed_cells} cells were taken from an earlier run's saved state."
    if result.resume_command:
        text += (" Run the same command again to resume (finished cells are not rendered "
                 f"again): <code>{html.escape(result.resume_command)}</code>")
    return f"<p class='partial'>{text}</p>"


__all__ = ["cell_header", "cell_rows", "findings_banners", "fmt", "partial_banner",
           "summary_header", "summary_rows", "table"]
