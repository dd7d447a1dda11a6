"""What ``mcrt check`` shows and writes: the table, ``results.json``, figures, ``report.html``.

``write_report(directory, ...)`` writes, each file atomically:

* ``points.png``: the points of two pixels (film dimension, the spectrum check's N);
* ``mse.png``: MSE against N per integrand (bars: its 95% intervals) with the
  fitted power law and independent sampling's N^-1 through the first point (the
  rate check);
* ``radial.png``: the radially averaged power spectrum (white noise = 1);
* ``results.json``: sampler, parameters, seed, budget and every check with its
  numbers (non-finite numbers as ``null``);
* ``report.html``: the command and software, the table and the figures (linked,
  next to it).
"""

from __future__ import annotations

import html
import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import atomic_path
from ..core.jsonfile import write_json
from ..core.provenance import html_note
from ..samplers import registry
from .check import CheckResult, budget_for

#: What each row checks, for the report (the margins are in :mod:`.check`,
#: :mod:`.check_claims` and :mod:`.check_stats`).
ROWS: dict[str, str] = {
    "determinism": "two fresh instances with the same seed draw the same bits",
    "range": "every value is finite and in [0, 1)",
    "clone": "a clone made mid-stream draws what the original draws",
    "fork": "a fork, seeded again, draws what a fresh instance draws",
    "seeding": "another seed changes the values of every call",
    "pixels": "no call gives other pixels the same values, beyond chance (a quadrature "
              "film and an unshifted table's sets are shared by design: reported)",
    **{name: f"claim: {text}" for name, text in registry.CLAIMS.items()},
    "unbiasedness": "mean estimate of each integrand (and of a product over two dimensions) "
                    "equals its value: t tests, Holm's correction at alpha 1e-3 (a quadrature "
                    "sampler's film terms are reported, not tested)",
    "mse_rate": "MSE falls at least as fast as independent sampling's N^-1 (N^-1.3 on the "
                "disk for stratified, net and min-distance claims)",
    "discrepancy": "L2-star discrepancy no worse than independent points'",
    "spectrum": "power at low frequencies (f < 0.5) no higher than white noise's",
}


def verdict(results: list[CheckResult]) -> str:
    """One line: all hold, or which fail."""
    failed = [r.name for r in results if r.status == "FAIL"]
    skipped = sum(r.skipped for r in results)
    extra = f" ({skipped} skipped)" if skipped else ""
    if failed:
        return f"{len(failed)} of {len(results)} checks FAIL: {', '.join(failed)}{extra}"
    return f"all {len(results) - skipped} checks hold{extra}"


def table_lines(results: list[CheckResult]) -> list[str]:
    """The printed table: property, result, figure, detail."""
    width = max(len(r.figure) for r in results)
    lines = [f"{'property':13s} {'result':6s} {'figure':{width}s} detail"]
    lines += [f"{r.name:13s} {r.status:6s} {r.figure:{width}s} {r.detail}" for r in results]
    return lines


def _plain(value: Any) -> Any:
    """JSON-safe: non-finite floats become None, numpy scalars Python numbers."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def summary(name: str, params: dict[str, Any], seed: int, quick: bool,
            results: list[CheckResult], spp: int | None = None) -> dict[str, Any]:
    """The content of ``results.json`` (``spp``: ``--spp``, if given)."""
    info = registry.info(name)
    return _plain({
        "sampler": name, "kind": info.kind, "summary": info.summary,
        "claims": sorted(info.claims), "params": params, "seed": seed, "quick": quick,
        "spp": spp, "budget": asdict(budget_for(quick, spp)),
        "passed": all(r.status != "FAIL" for r in results), "verdict": verdict(results),
        "checks": [{"name": r.name, "status": r.status, "passed": r.passed,
                    "skipped": r.skipped, "figure": r.figure, "detail": r.detail,
                    "values": r.values} for r in results]})


def _data(results: list[CheckResult], key: str) -> Any:
    return next((r.data[key] for r in results if key in r.data), None)


def _figures(out: Path, name: str, results: list[CheckResult],
             record: dict[str, str]) -> list[str]:
    """Draw the figures whose data the checks produced (``record``'s command in
    each PNG's text); returns their file names."""
    from ..core.provenance import png_text
    from . import plots

    text = png_text(record)

    written = []
    points = _data(results, "points")
    if points is not None:
        n = points.shape[1]
        k = math.isqrt(n)
        grid = k if "stratified" in registry.info(name).claims and k * k == n else None
        fig = plots.new_figure(7.0, 3.6)
        for i, ax in enumerate(fig.subplots(1, len(points))):
            plots.plot_point_set(ax, points[i], grid=grid, title=f"{name}: pixel {i}, N = {n}")
        plots.save_figure(fig, out / "points.png", text=text)
        written.append("points.png")
    convergence = _data(results, "convergence")
    if convergence is not None:
        fig = plots.new_figure(4.0 * len(convergence), 3.8)
        axes = fig.subplots(1, len(convergence))
        for ax, (integrand, conv) in zip(axes, convergence.items(), strict=True):
            if not conv.points:
                continue
            fit = conv.fit()
            n = np.array([p.n for p in conv.points], dtype=np.float64)
            mse = np.array([p.summary.mse for p in conv.points])
            low, high = np.array([p.summary.interval() for p in conv.points]).T
            plots.plot_convergence(ax, [(f"{name} (slope {fit.slope:+.2f})", n, mse, low, high)],
                                   reference_slopes=(-1.0,), title=f"MSE, {integrand}")
            if math.isfinite(fit.slope):
                ax.plot(n, [fit.mse_at(x) for x in n], color="tab:red", lw=0.8, ls="--")
        plots.save_figure(fig, out / "mse.png", text=text)
        written.append("mse.png")
    radial = _data(results, "radial")
    if radial is not None:
        fig = plots.new_figure(5.0, 3.6)
        plots.plot_radial_power(fig.add_subplot(), radial, label=name,
                                title=f"{name}: radially averaged power, N = {radial.n_points} "
                                      f"({radial.n_sets} pixels)")
        plots.save_figure(fig, out / "radial.png", text=text)
        written.append("radial.png")
    return written


_STYLE = ("body{font-family:sans-serif;max-width:70em;margin:1em auto;padding:0 1em}"
          "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:.3em .5em;"
          "text-align:left;vertical-align:top}.FAIL{background:#fdd;font-weight:bold}"
          ".pass{background:#dfd}.skip{background:#eee}img{max-width:100%}")


def render_html(data: dict[str, Any], figures: list[str]) -> str:
    """``report.html`` for :func:`summary`'s ``data`` and the figure files."""
    e = html.escape
    params = ", ".join(f"{k}={v}" for k, v in data["params"].items()) or "none"
    spp = f", --spp {data['spp']}" if data.get("spp") else ""
    rows = "".join(
        f"<tr><td><b>{e(c['name'])}</b><br><small>{e(ROWS.get(c['name'], ''))}</small></td>"
        f"<td class='{e(c['status'])}'>{e(c['status'])}</td><td>{e(c['figure'])}</td>"
        f"<td>{e(c['detail'])}</td></tr>" for c in data["checks"])
    images = "".join(f"<h2>{e(f.removesuffix('.png'))}</h2><img src='{e(f)}' alt='{e(f)}'>"
                     for f in figures)
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>mcrt check "
            f"{e(data['sampler'])}</title><style>{_STYLE}</style></head><body>"
            f"<h1>mcrt check {e(data['sampler'])}</h1>"
            f"<p>{e(data['summary'])} ({e(data['kind'])}); claims: "
            f"{e(', '.join(data['claims']) or 'none')}; parameters: {e(params)}; seed "
            f"{data['seed']}{', quick budget' if data['quick'] else ''}{spp}.</p>"
            f"{html_note(data)}"
            f"<p><b>{e(data['verdict'])}</b></p><table><tr><th>property</th><th>result</th>"
            f"<th>figure</th><th>detail</th></tr>{rows}</table>{images}"
            f"<p><small>Every check uses fixed seeds; the margins are documented in "
            f"mcrt.analysis.check, check_claims and check_stats. Numbers: results.json."
            f"</small></p></body></html>\n")


def write_report(out: Path, name: str, params: dict[str, Any], seed: int, quick: bool,
                 results: list[CheckResult], spp: int | None = None,
                 record: dict[str, str] | None = None) -> list[str]:
    """Write the figures, ``results.json`` and ``report.html`` to ``out``; returns
    the names of the files written. ``record``: how the run was made (its
    ``command`` and the versions), added to ``results.json``."""
    figures = _figures(out, name, results, record or {})
    data = {**summary(name, params, seed, quick, results, spp), **(record or {})}
    write_json(out / "results.json", data)
    with atomic_path(out / "report.html") as tmp:
        Path(tmp).write_text(render_html(data, figures), encoding="utf-8")
    return [*figures, "results.json", "report.html"]
