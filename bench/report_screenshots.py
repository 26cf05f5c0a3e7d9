"""Screenshots of the demo's HTML report in headless Chromium, one per section, kept in ``docs/report/``.

Usage: ``.venv/bin/python -m bench.report_screenshots [REPORT.html]`` from the checkout (default
``demo-out/report/report.html``, what ``make demo`` writes; ``python -m bench.bench_demo --keep DIR``
keeps one too). The page is rendered 1400 px wide, as a reader's browser window, and cut into its
sections by their margin bands (:mod:`tests.support.chromium`); each section is written as
``docs/report/<section>.png`` and ``docs/report/README.md`` lists them with what to look at.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from sindy_ekf.report.blocks import SECTIONS
from tests.support.chromium import full_page, save_png, section_images

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "report"
DEFAULT_REPORT = Path("demo-out") / "report" / "report.html"
LOOK_AT = {  # section -> what a reader checks in its screenshot
    "overview": "runs with their gaps counted; driven paths broken where the poses have gaps",
    "calibration": "estimates rounded to two digits of their standard deviation; the global test of s0^2 in words",
    "synchronisation": "clock and baseline figures with gaps left open; the hub model's legend in a panel of its own",
    "poses": "z about its mean in mm, no offset label; pose and sigma lines broken at prism losses",
    "identification": "every grid cell labelled, 'diverged' where a 5 s error is infinite, the inf rows explained",
    "evaluation": "the models explained under the table",
    "estimation": "GNSS fixes and 3-sigma bands, several outages of each length shaded, the estimators explained",
    "diagnosis": "the residual panel in two blocks large enough to read; the families explained",
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    report = Path(argv[0]) if argv else DEFAULT_REPORT
    if not report.is_file():
        print(f"report_screenshots: {report}: no report (run `make demo` or name a report.html)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="report-shots-") as tmp:
        img, rows = full_page(report, Path(tmp) / "page.png")
    cuts = section_images(img, rows)
    lines = ["# The report, section by section", "",
             f"Screenshots of the demo's report (`python -m bench.report_screenshots`, headless Chromium, a "
             f"{img.shape[1]} px wide window), one per section, with what each shows.", ""]
    for sid, title in SECTIONS:
        if sid not in cuts:
            lines += [f"- {title}: not rendered", ""]
            continue
        path = save_png(cuts[sid], DOCS / f"{sid}.png")
        look = LOOK_AT.get(sid, "")
        lines += [f"## {title}", "", f"{look[:1].upper()}{look[1:]}.", "", f"![{title}]({path.name})", ""]
        print(f"{path.relative_to(ROOT)}: {cuts[sid].shape[1]} x {cuts[sid].shape[0]} px")
    (DOCS / "README.md").write_text("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
