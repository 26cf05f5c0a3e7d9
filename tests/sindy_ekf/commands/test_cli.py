"""Bad input at the command line, for every command that exists: one-line errors, non-zero exits,
no traceback unless ``--verbose``; and the common options every command must take.

Cases (the issue's list): a path that is not a campaign, a campaign with no test runs (no train
runs for ``identify``), an output folder that cannot be written (its parent is a regular file:
unwritable even for root, unlike a chmod).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from groundfloor import progress
from groundfloor.errors import InputError
from sindy_ekf import cli

CAMPAIGN_COMMANDS = {  # command -> extra arguments after CAMPAIGN
    "preprocess": lambda tmp, model: ["--out", str(tmp / "pre_out")],
    "identify": lambda tmp, model: ["--out", str(tmp / "model_out.json"), "--quick"],
    "evaluate": lambda tmp, model: ["--model", str(model)],
    "benchmark": lambda tmp, model: ["--model", str(model)],
    "diagnose": lambda tmp, model: ["--model", str(model)],
    "report": lambda tmp, model: ["--out", str(tmp / "report_out")],
}
SCORING = ("evaluate", "benchmark", "diagnose", "report")  # they score on the test runs


def existing(commands) -> list[str]:
    """Return the commands of ``commands`` that this installation has."""
    _, modules = cli.build_parser()
    return [c for c in commands if c in modules]


def write_trajectory_campaign(root: Path, splits: dict[str, str], seconds: float = 30.0, seed: int = 0) -> Path:
    """Write a small trajectory campaign (data contract part 2) of a first-order vehicle."""
    rng = np.random.default_rng(seed)
    runs = []
    for k, (name, split) in enumerate(splits.items()):
        t = np.arange(0.0, seconds, 0.02)
        u1 = 0.6 * np.sin(2 * np.pi * t / 9.0 + k) + 0.2
        u2 = 0.5 * np.sin(2 * np.pi * t / 5.0 + 2 * k)
        vx = np.zeros_like(t)
        omega = np.zeros_like(t)
        for i in range(1, t.size):  # v_dot = (u - v) / 0.3 s, Euler at 50 Hz
            vx[i] = vx[i - 1] + 0.02 * (u1[i - 1] - vx[i - 1]) / 0.3
            omega[i] = omega[i - 1] + 0.02 * (u2[i - 1] - omega[i - 1]) / 0.3
        yaw = np.cumsum(omega) * 0.02
        x = np.cumsum(vx * np.cos(yaw)) * 0.02 + rng.normal(0, 1e-4, t.size)
        y = np.cumsum(vx * np.sin(yaw)) * 0.02 + rng.normal(0, 1e-4, t.size)
        d = root / "runs" / name
        d.mkdir(parents=True)
        np.savetxt(d / "poses.csv", np.column_stack([t, x, y, yaw]), delimiter=",", header="t,x,y,yaw", comments="")
        np.savetxt(d / "inputs.csv", np.column_stack([t, u1, u2]), delimiter=",", header="t,u1,u2", comments="")
        runs.append({"name": name, "split": split})
    (root / "campaign.yaml").write_text(yaml.safe_dump({"name": root.name, "kind": "trajectory", "runs": runs}))
    return root


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    """A valid model file (a first-order model written through the model's own writer)."""
    from identification.sindy.model import model_from_terms

    path = tmp_path_factory.mktemp("model") / "model.json"
    model_from_terms({"vx": {"vx": -3.0, "u1": 3.0}, "omega": {"omega": -3.0, "u2": 3.0}},
                     hyperparameters={"s": 0.0, "tau": 2.0, "alpha": 1.0, "T": 0.1}).to_json(path)
    return path


def run_cli(argv, capsys) -> tuple[int, str, str]:
    """Return (exit code, stdout, stderr) of the CLI run in this process."""
    code = cli.main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def assert_one_line_error(code: int, err: str, culprit: str) -> None:
    assert code != 0
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith(("WARNING", "INFO", "DEBUG"))
             and not re.search(r"\d+%\|", ln)]  # log records and progress bars are not the error
    assert len(lines) == 1, err
    assert culprit in lines[0], lines[0]


@pytest.mark.parametrize("command", existing(CAMPAIGN_COMMANDS))
def test_not_a_campaign(command, tmp_path, model_file, capsys):
    bogus = tmp_path / "holiday_photos"
    bogus.mkdir()
    (bogus / "IMG_0001.jpg").write_bytes(b"\xff\xd8")
    code, _, err = run_cli([command, bogus, *CAMPAIGN_COMMANDS[command](tmp_path, model_file)], capsys)
    assert code == 2
    assert_one_line_error(code, err, str(bogus))
    assert "not a campaign" in err


@pytest.mark.parametrize("command", existing(SCORING))
def test_campaign_without_test_runs(command, tmp_path, model_file, capsys):
    camp = write_trajectory_campaign(tmp_path / "only_train", {"run_a": "train", "run_b": "train"})
    code, _, err = run_cli([command, camp, *CAMPAIGN_COMMANDS[command](tmp_path, model_file)], capsys)
    assert code == 2
    assert_one_line_error(code, err, "test")


def test_identify_without_train_runs(tmp_path, model_file, capsys):
    camp = write_trajectory_campaign(tmp_path / "only_test", {"run_a": "test"})
    code, _, err = run_cli(["identify", camp, *CAMPAIGN_COMMANDS["identify"](tmp_path, model_file)], capsys)
    assert code == 2
    assert_one_line_error(code, err, "train")


@pytest.fixture(scope="module")
def good_campaign(tmp_path_factory) -> Path:
    return write_trajectory_campaign(tmp_path_factory.mktemp("good") / "good",
                                     {"run_a": "train", "run_b": "train", "run_c": "test"})


OUTPUT_CASES = {  # command -> argv with the output below a regular file ``blocker``
    "report": lambda camp, blocker: ["report", camp, "--out", blocker / "report"],
    "demo": lambda camp, blocker: ["demo", "--out", blocker / "demo"],
    "simulate": lambda camp, blocker: ["simulate", blocker / "campaign"],
    "identify": lambda camp, blocker: ["identify", camp, "--out", blocker / "model.json", "--quick"],
}


KNOWN_BAD = {  # command -> what it does wrong today (the test flips to XPASS, and fails, once fixed)
}


@pytest.mark.parametrize("command", [pytest.param(c, marks=pytest.mark.xfail(reason=KNOWN_BAD[c], strict=True))
                                     if c in KNOWN_BAD else c for c in existing(OUTPUT_CASES)])
def test_unwritable_output(command, good_campaign, tmp_path, capsys):
    blocker = tmp_path / "blocker"
    blocker.write_text("a regular file, not a folder")
    code, _, err = run_cli(OUTPUT_CASES[command](good_campaign, blocker), capsys)
    assert_one_line_error(code, err, str(blocker))
    assert code == 2, err  # bad input, not an internal error


def test_verbose_shows_the_traceback(tmp_path, capsys):
    # without --verbose one line (tests above); with it the exception propagates with its traceback
    with pytest.raises(InputError, match="not a campaign"):
        cli.main(["report", str(tmp_path), "--out", str(tmp_path / "r"), "--verbose"])


def test_every_command_takes_quiet_and_verbose():
    parser, modules = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(modules) >= {"simulate", "preprocess", "identify", "evaluate", "report", "demo"}
    for name in modules:
        options = sub.choices[name]._option_string_actions
        assert "--quiet" in options and "--verbose" in options, name


def test_quiet_switches_progress_bars_off(tmp_path, capsys):
    progress.enable(True)
    try:
        run_cli(["report", tmp_path, "--out", tmp_path / "r", "--quiet"], capsys)
        assert progress._enabled is False
        run_cli(["report", tmp_path, "--out", tmp_path / "r"], capsys)
        assert progress._enabled is True
    finally:
        progress.enable(False)


def test_pose_gaps_are_summarised_once_not_warned_per_run(tmp_path, model_file, capsys):
    # a prism lost for 2 s in each test run: expected, so one summary line for the command, no warning per run
    root = write_trajectory_campaign(tmp_path / "gappy", {"run_a": "test", "run_b": "test", "run_c": "train"})
    for name in ("run_a", "run_b"):
        poses = root / "runs" / name / "poses.csv"
        rows = poses.read_text().splitlines()
        kept = [r for r in rows[1:] if not 10.0 <= float(r.split(",")[0]) < 12.0]
        poses.write_text("\n".join([rows[0], *kept]) + "\n")
    code, _, err = run_cli(["evaluate", root, "--model", model_file], capsys)
    assert code == 0, err
    summary = [line for line in err.splitlines() if "pose gaps" in line]
    assert summary == ["sindy-ekf evaluate: pose gaps (a prism lost; never bridged): 2 in 2 runs (run_a 1, run_b 1)"]
    assert "gaps=" not in err and "WARNING" not in err
    code, _, err = run_cli(["evaluate", root, "--model", model_file, "--quiet"], capsys)
    assert code == 0 and "pose gaps" not in err
