"""Measurement-level findings of preprocessing, told as cause, correction and gain (thesis 5.2).

Preprocessing (``identification.preprocessing.preprocess``) discovers two things in the raw tracker data and
corrects them; its ``preprocess.json`` records the numbers. This module reads them back and
reports them in the diagnosis's language:

- **timing offset** (thesis 5.2.2, eqs. 5.15 to 5.24): the distance between the two prisms, a
  rigid baseline, changes with the driving speed when one tracker's samples are late; the cause
  is an extra offset of that tracker's clock, the correction shifts its samples, the gain is the
  drop of the baseline's RMS variation and of its correlation with the speed;
- **hub eccentricity** (thesis 5.2.3, eq. 5.25): what is left of the baseline variation follows
  the turning hubs' azimuths; the cause is the prisms sitting off the hubs' rotation axes, the
  correction is the eq. 5.25 model, the gain the drop of the baseline RMS.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from groundfloor.errors import InputError

REPORT_FILE = "preprocess.json"


@dataclass(frozen=True)
class Finding:
    """One measurement-level discrepancy: what it is, its estimate, the correction and its gain."""

    name: str  # "timing_offset" or "hub_eccentricity"
    cause: str
    estimate: dict
    correction: str
    gain: dict  # {"baseline_rms_m": {"before", "after"}, ...}
    runs: int

    def to_dict(self) -> dict:
        """Return a JSON-ready dict."""
        return {"name": self.name, "cause": self.cause, "estimate": self.estimate, "correction": self.correction,
                "gain": self.gain, "runs": self.runs}


def find_report(campaign: str | Path) -> Path | None:
    """Return the ``preprocess.json`` of a campaign (its own, or that of its preprocessing cache), or None."""
    root = Path(campaign)
    for cand in (root / REPORT_FILE, root / ".sindy-ekf" / "preprocessed" / REPORT_FILE):
        if cand.is_file():
            return cand
    return None


def _median(values) -> float:
    vals = [float(v) for v in values if v is not None and np.isfinite(v)]
    return float(np.median(vals)) if vals else float("nan")


def findings_from_report(report: dict, source: str = REPORT_FILE) -> list[Finding]:
    """Return the findings in a ``preprocess --json`` dict (medians over runs).

    Raises
    ------
    InputError
        If ``runs`` is missing or not a mapping.
    """
    runs = report.get("runs") if isinstance(report, dict) else None
    if not isinstance(runs, dict):
        raise InputError(f"{source}: key runs is missing or not a mapping")
    out = []
    offs = [r.get("at960_extra_offset_s") for r in runs.values()]
    if any(v is not None for v in offs):
        te = [r.get("timing_error") or {} for r in runs.values()]
        bl = [r.get("baseline_rms_m") or {} for r in runs.values()]
        tracker = next((r.get("extra_offset_tracker") for r in runs.values() if r.get("extra_offset_tracker")), "at960")
        r_before = _median([t.get("r_baseline_speed_before") for t in te])
        out.append(Finding(
            "timing_offset",
            f"the prism baseline changes with the speed (median correlation r = {r_before:.2f}): "
            f"the {tracker} samples are late by an extra clock offset",
            {"extra_offset_s": _median(offs),
             "extra_offset_std_s": _median([r.get("at960_extra_offset_std_s") for r in runs.values()]),
             "tracker": tracker},
            f"{tracker} sample times shifted by the offset that minimises the baseline spread (eqs. 5.15 to 5.24)",
            {"baseline_rms_m": {"before": _median([b.get("before") for b in bl]),
                                "after": _median([b.get("after") for b in bl])},
             "r_baseline_speed": {"before": r_before, "after": _median([t.get("r_baseline_speed_after") for t in te])}},
            len(runs)))
    hubs = [r["hub"] for r in runs.values() if isinstance(r.get("hub"), dict)]
    if hubs:
        out.append(Finding(
            "hub_eccentricity",
            "the remaining baseline variation follows the turning hubs' azimuths: the prisms sit off "
            "the hubs' rotation axes",
            {"r1_m": _median([h.get("r1") for h in hubs]), "r2_m": _median([h.get("r2") for h in hubs]),
             "r1_std_m": _median([h.get("r1_std") for h in hubs]), "r2_std_m": _median([h.get("r2_std") for h in hubs]),
             "phi1_rad": _median([h.get("phi1_rad") for h in hubs]),
             "phi2_rad": _median([h.get("phi2_rad") for h in hubs])},
            "eccentricity model of eq. 5.25 fitted per run" + (" and applied to the poses"
                                                            if report.get("hub_correction") else ""),
            {"baseline_rms_m": {"before": _median([h.get("rms_before_m") for h in hubs]),
                                "after": _median([h.get("rms_after_m") for h in hubs])}},
            len(hubs)))
    return out


def measurement_findings(campaign: str | Path) -> list[Finding]:
    """Return the measurement-level findings of a campaign's preprocessing ([] for a campaign without it)."""
    path = find_report(campaign)
    if path is None:
        return []
    try:
        report = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: cannot read the preprocessing report ({exc})") from None
    return findings_from_report(report, str(path))
