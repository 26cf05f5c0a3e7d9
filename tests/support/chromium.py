"""Screenshots of the HTML report in headless Chromium, cut into its sections.

Shared by the report's rendering test and ``python -m bench.report_screenshots`` (which keeps
one screenshot per section in ``docs/report/``). Chromium is ``$CHROMIUM``, by default Debian's
``/usr/bin/chromium``, which ``make test`` installs; missing, :func:`chromium` raises saying how
to get it (the test fails, the script says so).
Each section of the report starts with a coloured band in its left margin
(:data:`sindy_ekf.report.blocks.SECTION_MARKERS`), which is how a screenshot is cut into
sections without a browser API.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image  # pillow: a test extra

from sindy_ekf.report.blocks import MARKER_WIDTH_PX, SECTION_MARKERS

CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))  # the Makefile installs it
WINDOW_WIDTH_PX = 1400
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars")


class ChromiumMissing(RuntimeError):
    """Headless Chromium is not installed where :data:`CHROMIUM` says."""


def chromium() -> Path:
    """Return the Chromium binary; raise :class:`ChromiumMissing`, saying how to install it, when it is missing."""
    if not CHROMIUM.exists():
        raise ChromiumMissing(f"headless Chromium ({CHROMIUM}) is missing: `make test` installs Debian's package "
                              "'chromium' (as root), or run `apt-get install chromium`, or set CHROMIUM to a "
                              "Chromium binary")
    return CHROMIUM


def screenshot(html_path: Path, png: Path, height: int, scale: float = 1.0,
               width: int = WINDOW_WIDTH_PX) -> np.ndarray:
    """Return the ``(height * scale, width * scale, 3)`` RGB screenshot of ``html_path`` (int16).

    ``scale`` is the device scale factor: 2 renders the page as a browser zoomed to 200 % on a
    screen of twice the pixel density (what a reader zooming in sees).
    """
    with tempfile.TemporaryDirectory(prefix="chromium-") as user_dir:
        cmd = [str(chromium()), *FLAGS, f"--user-data-dir={user_dir}", f"--screenshot={png}",
               f"--window-size={width},{height}", f"--force-device-scale-factor={scale:g}",
               Path(html_path).resolve().as_uri()]
        subprocess.run(cmd, capture_output=True, timeout=300, check=False)
    if not png.is_file():
        raise RuntimeError(f"Chromium wrote no screenshot of {html_path}")
    return np.asarray(Image.open(png).convert("RGB")).astype(np.int16)


def section_rows(img: np.ndarray, scale: float = 1.0) -> dict[str, tuple[int, int]]:
    """Return section id -> (first, last) screenshot row of its margin band."""
    band = img[:, int(MARKER_WIDTH_PX * scale) // 2]
    out = {}
    for sid, rgb in SECTION_MARKERS.items():
        rows = np.flatnonzero((np.abs(band - np.asarray(rgb)) <= 3).all(axis=1))
        if rows.size:
            out[sid] = (int(rows[0]), int(rows[-1]))
    return out


def full_page(html_path: Path, png: Path, scale: float = 1.0, height: int = 12000) -> tuple[np.ndarray, dict]:
    """Return the screenshot of the whole report and its section rows, the window grown until
    the last section ends above the window's bottom."""
    for _ in range(4):
        img = screenshot(html_path, png, height, scale)
        rows = section_rows(img, scale)
        if rows and max(r[1] for r in rows.values()) < img.shape[0] - 40 * scale:
            return img, rows
        height *= 2
    return img, rows


def section_images(img: np.ndarray, rows: dict[str, tuple[int, int]], scale: float = 1.0) -> dict[str, np.ndarray]:
    """Return section id -> the screenshot cut to that section (its band's rows, a margin kept)."""
    pad = int(8 * scale)
    return {sid: img[max(a - pad, 0):min(b + pad, img.shape[0])] for sid, (a, b) in rows.items()}


def save_png(img: np.ndarray, path: Path, width: int | None = None) -> Path:
    """Write an RGB screenshot as an optimised palette PNG (resized to ``width`` px when given); return the path."""
    im = Image.fromarray(np.clip(img, 0, 255).astype(np.uint8))
    if width is not None and im.width != width:
        im = im.resize((width, round(im.height * width / im.width)), Image.LANCZOS)
    path.parent.mkdir(parents=True, exist_ok=True)
    im.quantize(colors=256).save(path, optimize=True)  # a palette: a quarter of the size, no visible change
    return path


def render_images(images: list[tuple[str, int, int]], png: Path) -> list[np.ndarray]:
    """Return each image ``(src data URI, width px, height px)`` as Chromium draws it alone at that size.

    The images are stacked on one white page (one browser start for all) and cut out again: the
    references the report's screenshot is searched for.
    """
    tops, y = [], 0
    for _, _, h in images:
        tops.append(y)
        y += h + 10
    body = "".join(f'<img style="position: absolute; left: 0; top: {top}px" width="{w}" height="{h}" src="{src}">'
                   for (src, w, h), top in zip(images, tops))
    page = png.with_suffix(".html")
    page.write_text(f'<!DOCTYPE html><html><body style="margin: 0; background: #fff">{body}</body></html>')
    width = max([800, *(w for _, w, _ in images)])  # Chromium keeps a minimum window width
    img = screenshot(page, png, height=max(y, 1), width=width)
    return [img[top:top + h, :w] for (_, w, h), top in zip(images, tops)]
