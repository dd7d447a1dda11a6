"""A large study's report: its size against the float16 EXR of its images, and how fast it opens.

Builds the report of a made-up study without rendering (the StudyResult of
tests/analysis/test_study_plots.py's ``synthetic_result``: smooth made-up scenes plus noise
of each cell's MSE; default 2 scenes of 512x512, 10 samplers, 5 sample counts, 4
seeds: 100 cells) with :func:`mcrt.analysis.report.write_report`, then prints

* the size of the report directory without ``exr/`` (report.html, the viewer's
  data files, figures, results) against the size of every image its viewers
  show (the reference, and per cell the first seed, the mean, the variance and
  FLIP) written as float16 EXR (ZIP, OpenEXR's usual lossless compression; PIZ
  beside it), from the values the viewer shows; goal: at most 1.5x;
* how long headless Chromium (Debian's chromium and chromium-driver, through
  Selenium, as tests/analysis/test_report_viewer.py) takes, in a new browser each run,
  from navigating to ``report.html#viewer-0`` to the first image drawn and to
  every image on screen drawn, and from navigating to ``report.html`` to its
  load event (median of ``--runs``); goal: the first image within 2 s.

    python benchmarks/report_size.py                     # ~3 minutes on 2 cores
    python benchmarks/report_size.py --size 256 --runs 3 --out out/report_size
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the tests package: the synthetic StudyResult of the figure tests

SAMPLERS = ("uniform_grid", "jittered", "poisson_disk", "sobol", "zsobol", "independent",
            "stratified", "multijitter", "orthogonal", "ldsampler")


def build(out: Path, size: int, spp: tuple[int, ...]) -> float:
    """Write the report into ``out``; returns the seconds write_report took."""
    from mcrt.analysis.report import write_report
    from tests.analysis.test_study_plots import synthetic_result

    result = synthetic_result(samplers=SAMPLERS, spp=spp, smooth=True, renders=True,
                              sizes={"checkerboard": (size, size), "cornell_box": (size, size)})
    start = time.perf_counter()
    write_report(result, out)
    return time.perf_counter() - start


def folder_bytes(folder: Path, skip: str = "") -> int:
    return sum(p.stat().st_size for p in folder.rglob("*")
               if p.is_file() and not (skip and p.relative_to(folder).parts[0] == skip))


def half_exr_bytes(report: Path, compression: str) -> int:
    """Bytes of every image the viewer shows, each as a float16 EXR file."""
    import OpenEXR

    from mcrt.analysis.viewer.data import DATA_DIR, read_data_file

    kind = getattr(OpenEXR, f"{compression}_COMPRESSION")
    total = 0
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "image.exr"
        for data in sorted((report / DATA_DIR).rglob("*.js")):
            _, values = read_data_file(data)
            half = values.astype(np.float16)
            channels = ({c: np.ascontiguousarray(half[..., i]) for i, c in enumerate("RGB")}
                        if half.ndim == 3 else {"Y": half})
            with OpenEXR.File({"compression": kind, "type": OpenEXR.scanlineimage},
                              channels) as f:
                f.write(str(path))
            total += path.stat().st_size
    return total


def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1300,1000", "--force-device-scale-factor=1"):
        options.add_argument(arg)
    options.binary_location = shutil.which("chromium") or "chromium"
    return webdriver.Chrome(options=options,
                            service=Service(shutil.which("chromedriver") or "chromedriver"))


#: ms from navigation to every panel on screen drawn, or null while some are not.
ALL_DRAWN = """
var v = document.querySelector('.mcrt-viewer'), r = window.innerHeight, pending = 0;
v.querySelectorAll('.vw-panel').forEach(function (p) {
  var b = p.getBoundingClientRect(), c = p.querySelector('canvas');
  if (p.style.display !== 'none' && b.bottom > 0 && b.top < r
      && c.getAttribute('data-drawn') !== c.getAttribute('data-shows')) pending++;
});
return pending ? null : performance.now();
"""


def load_times(report: Path, runs: int) -> dict[str, list[float]]:
    """Per run (a new browser each): ms to the first image and to every image on
    screen of ``report.html#viewer-0``, and to the load event of ``report.html``."""
    times: dict[str, list[float]] = {"first image": [], "all on screen": [], "page load": []}
    url = report.resolve().as_uri()
    for _ in range(runs):
        driver = browser()
        try:
            driver.get(url)
            times["page load"].append(driver.execute_script(
                "var t = performance.getEntriesByType('navigation')[0];"
                "return t.loadEventEnd - t.startTime;"))
            driver.get("about:blank")
            driver.get(url + "#viewer-0")
            deadline = time.monotonic() + 60
            drawn = None
            while drawn is None and time.monotonic() < deadline:
                drawn = driver.execute_script(ALL_DRAWN)
                time.sleep(0.02)
            times["all on screen"].append(drawn if drawn is not None else float("nan"))
            times["first image"].append(driver.execute_script("return window.mcrtFirstImage"))
        finally:
            driver.quit()
    return times


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=512, help="image width and height (512)")
    p.add_argument("--spp", default="4,16,64,256,1024", help="sample counts (4,16,64,256,1024)")
    p.add_argument("--runs", type=int, default=5, help="browser runs (5)")
    p.add_argument("--out", type=Path, help="keep the report here (default: a temporary folder)")
    args = p.parse_args()
    spp = tuple(int(n) for n in args.spp.split(","))
    keep = args.out is not None
    out = args.out or Path(tempfile.mkdtemp(prefix="mcrt-report-size-"))
    try:
        seconds = build(out, args.size, spp)
        report = out / "report.html"
        total = folder_bytes(out, skip="exr")
        parts = {"report.html": report.stat().st_size,
                 "viewer/": folder_bytes(out / "viewer"),
                 "figures (*.png)": sum(f.stat().st_size for f in out.glob("*.png")),
                 "results.csv/json": sum(f.stat().st_size for f in out.glob("results.*"))}
        zip_, piz = half_exr_bytes(out, "ZIP"), half_exr_bytes(out, "PIZ")
        cells = 2 * len(SAMPLERS) * len(spp)
        print(f"study: 2 scenes x {len(SAMPLERS)} samplers x spp {args.spp} = {cells} cells "
              f"of {args.size}x{args.size}; write_report {seconds:.1f} s")
        print(f"report without exr/: {total / 1e6:.1f} MB ("
              + ", ".join(f"{k} {v / 1e6:.1f} MB" for k, v in parts.items()) + ")")
        print(f"exr/ (float32, not counted): {folder_bytes(out / 'exr') / 1e6:.1f} MB")
        print(f"float16 EXR of the images shown: ZIP {zip_ / 1e6:.1f} MB, PIZ {piz / 1e6:.1f} MB")
        print(f"size ratio: {total / zip_:.2f}x the ZIP files, {total / piz:.2f}x the PIZ ones "
              f"(goal <= 1.5x)")
        times = load_times(report, args.runs)
        for name, values in times.items():
            print(f"{name}: median {statistics.median(values):.0f} ms "
                  f"(runs: {', '.join(f'{v:.0f}' for v in values)})")
        print(f"goal: first image <= 2000 ms: "
              f"{'met' if statistics.median(times['first image']) <= 2000 else 'NOT met'}")
    finally:
        if not keep:
            shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
