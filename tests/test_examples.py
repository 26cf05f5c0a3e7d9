"""Every example's ``main()`` runs (so the examples cannot rot), and what it prints as its finding holds.

Parametrised over the ``examples/*.py`` that exist (helpers starting with ``_`` excluded). An
example whose own test file runs it (``tests/test_<name>.py``) is left to that file: not collected
here, rather than collected and skipped. The
findings are checked against something independent of the code under test: the baselines the
thesis compares with, and the simulator's true dynamics.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TESTS = Path(__file__).resolve().parent


def example_files() -> list[Path]:
    """Return the example scripts run here (not the ``_`` helpers, not those with their own test file)."""
    return sorted(p for p in EXAMPLES.glob("*.py")
                  if not p.name.startswith("_") and not (TESTS / f"test_{p.stem}.py").is_file())


def load(path: Path):
    """Import an example as a module from its file (examples import only the installed packages)."""
    spec = importlib.util.spec_from_file_location(f"example_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def check_identify_your_campaign(result: dict) -> None:
    e = {k: v["pos_err_5s_m"] for k, v in result["errors"].items()}
    # the identified model predicts better than both baselines of the thesis (5.3.8)
    assert e["sindy"] < 0.5 * e["unicycle"] < 0.5 * e["constant_velocity"], e
    assert result["errors"]["sindy"]["n_windows"] >= 10
    assert result["model"].complexity >= 2


def check_dead_reckoning_through_outage(result: dict) -> None:
    rms = {k: float(np.sqrt(np.mean(v ** 2))) for k, v in result["errors_m"].items()}
    assert result["n_outages"] >= 2
    # the identified model dead-reckons like the simulator's own dynamics, far better than the baselines
    assert rms["sindy"] < 0.5 * rms["lag"] and rms["sindy"] < 0.5 * rms["constant_velocity"], rms
    assert rms["sindy"] < 0.5 * rms["unicycle"], rms
    assert rms["sindy"] < 3.0 * rms["true_dynamics"] + 0.05, rms


def check_benchmark_estimators(result: dict) -> None:
    s = {k: v["ate_pos_m"] for k, v in result["estimators"].items()}
    assert set(s) >= {"dead_reckoning", "cv_ekf", "unicycle_ekf", "lag_ekf", "sindy_ekf", "sindy_graph"}
    assert s["sindy_ekf"] < s["lag_ekf"] < s["cv_ekf"], s  # the lag (the model this line always held)
    assert s["sindy_ekf"] < s["unicycle_ekf"], s
    # the smoother uses the fixes after each outage too: no worse than the filter
    assert s["sindy_graph"] <= 1.1 * s["sindy_ekf"], s
    assert all(np.isfinite(v["runtime_s"]) for v in result["estimators"].values())


def check_diagnose_hidden_effect(result: dict) -> None:
    # the simulator hid the effect: the diagnosis must name it, and the extension must not hurt
    assert result["verdict"] == result["hidden"], result
    assert result["after"]["pos_err_5s_m"] <= result["before"]["pos_err_5s_m"], result


CHECKS = {"diagnose_hidden_effect": check_diagnose_hidden_effect,
          "identify_your_campaign": check_identify_your_campaign,
          "dead_reckoning_through_outage": check_dead_reckoning_through_outage,
          "benchmark_estimators": check_benchmark_estimators}


@pytest.mark.parametrize("path", example_files(), ids=lambda p: p.stem)
def test_example_runs_and_its_finding_holds(path, capsys):
    module = load(path)
    assert (module.__doc__ or "").strip(), f"{path.name}: no docstring stating the problem and the model"
    assert "Problem" in module.__doc__ and "Model" in module.__doc__, path.name
    result = module.main()
    printed = capsys.readouterr().out
    assert printed.strip(), f"{path.name}: main() printed nothing"
    if path.stem in CHECKS:
        CHECKS[path.stem](result)
