"""The HTML report: self-contained, every section present, and every figure visible when rendered.

The rendering test opens the report in headless Chromium (``$CHROMIUM``, by default Debian's
``/usr/bin/chromium``, which ``make test`` installs; missing, the test fails saying how to get it)
and checks the screenshot's content: each section is found by its margin band colour, and every
figure embedded in a section (SVG, shown at its natural size) is found again in the screenshot
inside that section's band, by matching it, as Chromium draws it alone, against the screenshot
pixels (a blank, cut, shrunk or misplaced figure fails). With ``SINDY_EKF_UPDATE_DOCS=1`` the
screenshot is also saved, reduced, as ``docs/report_screenshot.png``.
"""

from __future__ import annotations

import base64
import contextlib
import io
import os
import re

import numpy as np
import pytest
from scipy.signal import fftconvolve

from groundfloor.errors import InputError
from identification.sindy.search import SearchGrid
from simulation.campaign import MIN_RUN_S, simulate_campaign
from simulation.truth import read_truth
from sindy_ekf.report.blocks import CONTENT_LEFT_PX, SECTION_MARKERS, SECTIONS, Section
from sindy_ekf.report.html import build_report, render_report
from sindy_ekf.stages.chain import run_chain
from tests.support import REPO
from tests.support.chromium import WINDOW_WIDTH_PX, render_images, screenshot, section_rows

DOCS_SHOT = REPO / "docs" / "report_screenshot.png"
# 4 grid points, 2 folds: a real search, small enough for the test budget
TINY_GRID = SearchGrid(s=(0.0005,), tau=(3.0,), alpha=(1.0, 10.0), T=(0.25, 0.5), n_folds=2)
FAST_ESTIMATORS = ("dead_reckoning", "cv_ekf", "sindy_ekf")  # the section's figures, in seconds
CORE = ("overview", "calibration", "synchronisation", "poses", "identification", "evaluation")
CONTENT_WIDTH_PX = WINDOW_WIDTH_PX - CONTENT_LEFT_PX - 24  # a section's padding on the right


@pytest.fixture(scope="module")
def report(small_campaign, tmp_path_factory):
    """The report of the small campaign, with what the library printed on stdout meanwhile."""
    out = tmp_path_factory.mktemp("report")
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        chain = run_chain(small_campaign, out, grid=TINY_GRID, estimators=FAST_ESTIMATORS)
        path = render_report(chain, out)
    return {"path": path, "chain": chain, "html": path.read_text(), "stdout": stdout.getvalue(), "out": out}


FIGURE = re.compile(r'<img alt="[^"]*" width="(\d+)" height="(\d+)" src="(data:image/(?:svg\+xml|png);base64,'
                    r'[A-Za-z0-9+/=]+)">')


def sections_of(html_text: str) -> dict[str, dict]:
    """Return section id -> {status, figures (declared count), images [(src, width, height)]} from the HTML."""
    out = {}
    parts = re.split(r'(?=<section id=")', html_text)
    for part in parts[1:]:
        m = re.match(r'<section id="(\w+)" data-status="(\w+)" data-figures="(\d+)"', part)
        images = [(src, int(w), int(h)) for w, h, src in FIGURE.findall(part)]
        out[m.group(1)] = {"status": m.group(2), "figures": int(m.group(3)), "images": images, "html": part}
    return out


def test_report_is_self_contained_and_walks_the_chain(report):
    html_text = report["html"]
    secs = sections_of(html_text)
    assert list(secs) == [sid for sid, _ in SECTIONS]
    assert "<script" not in html_text.lower()
    # nothing fetched from anywhere: no URL in any src/href, no @import, every image inline
    assert not re.search(r'(src|href)="(?!data:|#)', html_text)
    assert "@import" not in html_text and "url(" not in html_text
    for sid in CORE:
        assert secs[sid]["status"] == "ok", (sid, secs[sid]["html"][:400])
        assert secs[sid]["figures"] >= 1 and len(secs[sid]["images"]) == secs[sid]["figures"]
    for sid, sec in secs.items():  # vector figures, none wider than the page (a shrunk figure's text is too small)
        for src, w, _ in sec["images"]:
            assert src.startswith("data:image/svg+xml;base64,") and w <= CONTENT_WIDTH_PX, (sid, w)
    for sid, sec in secs.items():  # a section without content names its reason
        if sec["status"] != "ok":
            assert re.search(r"not available: |failed: |could not be built", sec["html"]), sid
    # the identified model is the one written beside the report, and its equations are shown
    model = report["chain"].model
    assert (report["out"] / "model.json").is_file()
    assert model.equations().splitlines()[0].split("=")[0].strip() in html_text
    # the evaluation table holds the numbers the chain computed
    assert f"{100 * report['chain'].evaluation['sindy'].pos_err_5s_m:.2f}" in secs["evaluation"]["html"]
    # calibration agrees with the simulator's truth (survey of tables 6.1-6.3) to the table's digits
    truth = read_truth(report["chain"].campaign_path, states=False)
    t_true = np.asarray(truth.transform["translation_m"])
    assert np.allclose(report["chain"].calibration.transform.t_at960_ltd800, t_true, atol=1e-4)


def test_library_prints_nothing_on_stdout(report):
    # the whole chain (preprocess, search, evaluation, diagnosis) and rendering ran in the fixture
    assert report["stdout"] == ""


def blocks(img: np.ndarray, k: int = 4) -> np.ndarray:
    """Return the means of ``k`` x ``k`` pixel blocks of an (h, w, 3) image (edges cropped)."""
    h, w = img.shape[0] // k * k, img.shape[1] // k * k
    return img[:h, :w].reshape(h // k, k, w // k, k, 3).mean(axis=(1, 3))


def find_figure(img: np.ndarray, ref: np.ndarray, rows: tuple[int, int]) -> tuple[float, int, int]:
    """Return (mismatch, x, y) of the best place of the figure ``ref`` (as Chromium draws it) within the rows.

    Candidate places come from the least squared difference of the darkness of 4 x 4 blocks
    (by FFT, anywhere in the section's rows), refined pixel by pixel around the best three; each
    is scored by the mean absolute difference of 8 x 8 block means relative to the difference to
    a blank (white) area: 0 is a perfect match, 1 is as bad as no figure at all. Blocks of 8
    forgive how a vector figure's thin lines are antialiased at another sub-pixel offset: on the
    demo's report a figure scores at most 0.15 where it is, another figure of the same size at
    the same place about 1.
    """
    k, k_score = 4, 8
    strip = img[rows[0]:rows[1] + 1]
    h, w = ref.shape[:2]
    if strip.shape[0] < h or strip.shape[1] < w:
        return np.inf, -1, -1
    ref_blocks = blocks(ref, k_score)
    blank = np.abs(255 - ref_blocks).mean()
    if blank < 1.0:  # a blank figure is found anywhere: it shows nothing
        return np.inf, -1, -1
    d_s, d_r = 255 - blocks(strip, k).mean(axis=2), 255 - blocks(ref, k).mean(axis=2)
    # sum over a window of (s - r)^2 = sum s^2 - 2 sum s r + sum r^2, each by one FFT
    ssd = (fftconvolve(d_s ** 2, np.ones_like(d_r), mode="valid") - 2 * fftconvolve(d_s, d_r[::-1, ::-1], mode="valid")
           + (d_r ** 2).sum())
    best = (np.inf, -1, -1)
    for flat in np.argsort(ssd, axis=None)[:3]:
        by, bx = np.unravel_index(flat, ssd.shape)
        for y in range(max(k * by - k + 1, 0), min(k * by + k, strip.shape[0] - h + 1)):
            for x in range(max(k * bx - k + 1, 0), min(k * bx + k, strip.shape[1] - w + 1)):
                mism = np.abs(blocks(strip[y:y + h, x:x + w], k_score) - ref_blocks).mean() / blank
                best = min(best, (float(mism), x, rows[0] + y))
    return best


def test_rendered_report_shows_every_section_and_figure(report, tmp_path):
    secs = sections_of(report["html"])
    height = 16000
    for _ in range(2):  # grow the window until the last section ends above its bottom
        img = screenshot(report["path"], tmp_path / "report.png", height)
        rows = section_rows(img)
        if max(r[1] for r in rows.values()) < height - 40:
            break
        height *= 2
    assert set(rows) == set(SECTION_MARKERS), f"sections not rendered: {set(SECTION_MARKERS) - set(rows)}"
    order = [rows[sid] for sid, _ in SECTIONS]
    assert all(a[1] < b[0] for a, b in zip(order, order[1:])), "sections overlap or are out of order"
    assert img[:rows["overview"][0]].min() < 100, "no visible header above the first section"
    images = [im for sec in secs.values() for im in sec["images"]]
    refs = iter(render_images(images, tmp_path / "figures.png"))
    for sid, sec in secs.items():
        for k, _ in enumerate(sec["images"]):
            mism, x, y = find_figure(img, next(refs), rows[sid])
            assert mism < 0.25, f"section {sid}: figure {k + 1} not visible in the screenshot (mismatch {mism:.2f})"
    if os.environ.get("SINDY_EKF_UPDATE_DOCS") == "1":
        from PIL import Image  # pillow: a test extra

        end = max(r[1] for r in rows.values()) + 30
        shot = Image.fromarray(img[:end].astype(np.uint8)).resize((700, end // 2), Image.LANCZOS)
        DOCS_SHOT.parent.mkdir(parents=True, exist_ok=True)
        shot.quantize(colors=128).save(DOCS_SHOT, optimize=True)


def test_figure_search_rejects_a_missing_figure(report, tmp_path):
    # the check above can fail: a figure blanked out of the page is not found
    src, w, h = sections_of(report["html"])["overview"]["images"][0]
    white = (f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}">'
             f'<rect width="{w}" height="{h}" fill="#fff"/></svg>')
    page = tmp_path / "blank.html"
    page.write_text(report["html"].replace(src, "data:image/svg+xml;base64," + base64.b64encode(white.encode()).decode()))
    img = screenshot(page, tmp_path / "blank.png", 4000)
    (ref,) = render_images([(src, w, h)], tmp_path / "ref.png")
    mism, _, _ = find_figure(img, ref, section_rows(img)["overview"])
    assert mism > 0.5


def test_trajectory_campaign_has_no_calibration_section(report, small_trajectory, tmp_path):
    # a model given, only the stages a trajectory campaign can and cannot have
    chain = run_chain(small_trajectory, tmp_path, model=report["out"] / "model.json",
                      stages=("calibration", "synchronisation", "identification"))
    assert chain.kind == "trajectory" and chain.search is None
    path = render_report(chain, tmp_path, sections=("overview", "calibration", "synchronisation", "identification"))
    secs = sections_of(path.read_text())
    for sid in ("calibration", "synchronisation"):
        assert secs[sid]["status"] == "absent"
        assert "trajectory campaign holds no raw tracker data" in secs[sid]["html"]
    assert secs["identification"]["status"] == "ok" and "loaded from" in secs["identification"]["html"]


def test_report_write_is_atomic(report, tmp_path, monkeypatch):
    import sindy_ekf.report.html as rep

    (tmp_path / "report.html").write_text("old")

    def broken(*a, **k):
        raise RuntimeError("rendering failed midway")

    monkeypatch.setattr(rep, "html_from_sections", broken)
    with pytest.raises(RuntimeError):
        rep.render_report(report["chain"], tmp_path, sections=("overview",))
    assert (tmp_path / "report.html").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.html"]


def test_report_bad_output_folder_named(report, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(InputError, match=r"a_file/out: output folder is not writable"):
        build_report(report["chain"].campaign_path, blocker / "out")
    with pytest.raises(InputError, match=r"a_file: output exists and is not a folder"):
        build_report(report["chain"].campaign_path, blocker)


def test_simulator_prints_nothing(tmp_path, capsys):
    # the other library entry points ran in the report fixture; the simulator was run by conftest
    truth = simulate_campaign(tmp_path / "c", seed=4, minutes=9 * MIN_RUN_S / 60.0)
    assert len(truth.runs) == 9
    assert capsys.readouterr().out == ""


def test_a_broken_figure_is_named_and_the_rest_kept():
    from matplotlib.figure import Figure  # matplotlib only in plot modules and here, to draw one

    def good():
        fig = Figure(figsize=(4, 3))
        fig.subplots().plot([0, 1], [1, 0])
        return fig

    sec = Section("overview", "Campaign overview")
    sec.figures([(lambda: 1 / 0, "broken plot"), (good, "good plot")])
    text = sec.to_html()
    assert 'figure "broken plot" could not be drawn: ZeroDivisionError' in text
    assert sec.n_figures == 1 and text.count("data:image/svg+xml;base64,") == 1
    assert 'data-figures="1"' in text


def test_estimation_note_says_which_gnss_and_sensors_were_fused():
    # a benchmark on recorded fixes is not GNSS simulated from the truth; the gyro and odometry an
    # estimator fused are named with it (before, every report said "simulated" and named neither)
    from types import SimpleNamespace
    from sindy_ekf.report.sections import gnss_note
    rec = {"enu_to_local": {"enu_to_local_yaw_deg": -29.9976, "yaw_std_deg": 0.0045, "estimated": True}}
    config = {"estimators": {"sindy_ekf": {"sensors": ["gnss", "imu", "odometry"]}, "cv_ekf": {"sensors": ["gnss"]},
                             "lag_ekf": {"sensors": ["gnss", "imu"]}}}
    b = SimpleNamespace(recorded_gnss=rec, truth={"r": None}, profile="recorded", config=config,
                        scores={"cv_ekf": 0, "sindy_ekf": 0})  # lag_ekf not run
    note = gnss_note(b)
    assert "own recorded fixes" in note and "rotation estimated from the fixes against the truth: -29.998 +- 0.004 deg" in note
    assert "simulated" not in note
    assert note.endswith("; the gyro (imu.csv) fused by sindy_ekf; the wheel odometry (odometry.csv) fused by sindy_ekf")
    b = SimpleNamespace(recorded_gnss=None, truth={"r": None, "s": None}, profile="dgnss", config=None, scores={"cv_ekf": 0})
    assert gnss_note(b).startswith("GNSS profile dgnss (") and "simulated from the ground-truth poses of the 2 test" in gnss_note(b)
    # an antenna lever arm the fixes give away from the declared one is said beside it
    rec["lever_arm_fit"] = {"estimated_m": [-0.212, 0.102], "std_m": [0.027, 0.028], "declared_m": [0.0, 0.0],
                            "differs": True}
    b = SimpleNamespace(recorded_gnss=rec, truth={"r": None}, profile="recorded", config=None, scores={})
    assert gnss_note(b).endswith(". The fixes put the antenna at (-0.21 +- 0.03, 0.10 +- 0.03) m in the body frame, not "
                                 "at the declared (0.00, 0.00) m: the filters took it there, so part of their GNSS error "
                                 "is the antenna swinging around the body origin in turns")
    rec["lever_arm_fit"]["differs"] = False
    assert "antenna" not in gnss_note(b)
    assert "correlated" not in gnss_note(b)
    rec["enu_to_local"]["errors_correlated_over_runs"] = True  # a standalone receiver's wandering bias
    assert gnss_note(b).endswith("-29.998 +- 0.004 deg; the ground-truth poses of the 1 test runs are the truth. The "
                                 "fixes' errors stay correlated over most of every run (a receiver bias wandering for "
                                 "minutes), likely across runs too: the estimated rotation may be off by more than its "
                                 "stated std")


def test_evaluation_note_puts_the_cv_estimate_beside_the_test_score():
    # two folds 4 and 6 cm: s = 1.414 cm, t(0.975, 1) sqrt(1.5) s = +- 22.01 cm by hand; five folds of
    # 1.0 to 1.4 cm: s = 0.158 cm, t(0.975, 4) = 2.776, sqrt(1.2): +- 0.48 cm
    from types import SimpleNamespace
    from sindy_ekf.report.sections import cv_note
    two = SimpleNamespace(training={"cv": {"pos_err_5s_m": 0.05, "fold_pos_err_5s_m": [0.04, 0.06],
                                           "kind": "leave-one-group-out"}})
    assert cv_note(two, 0.2) == ("Cross-validation on the train runs (leave-one-group-out, 2 folds) estimated 5.00 cm "
                                 "at 5 s; the test runs gave 20.00 cm, inside the 95 % prediction interval of one "
                                 "more held-out group (+- 22.01 cm): nothing says the test runs are unlike the train "
                                 "groups; with 2 folds the interval is wider than the estimate itself, so the "
                                 "comparison says little.")
    five = SimpleNamespace(training={"cv": {"pos_err_5s_m": 0.012, "fold_pos_err_5s_m": [0.010, 0.011, 0.012, 0.013,
                                                                                           0.014]}})
    note = cv_note(five, 0.0175)
    assert "(5 folds) estimated 1.20 cm" in note and "outside the 95 % prediction interval" in note
    assert "(+- 0.48 cm)" in note and "NOT like the train groups" in note
    assert "inside" in cv_note(five, 0.0165) and "says little" not in cv_note(five, 0.0165)
    assert cv_note(SimpleNamespace(training={}), 0.1) == "" and cv_note(None, 0.1) == ""
    one = SimpleNamespace(training={"cv": {"pos_err_5s_m": 0.05, "fold_pos_err_5s_m": [0.05]}})
    assert cv_note(one, 0.5).endswith("(one fold: no spread to compare them by).")
