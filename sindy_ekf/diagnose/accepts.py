"""What ``diagnose`` accepts before any work: a model file of the campaign's variables and test runs
long enough to score it out of sample (one-line errors naming the file or the runs)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from groundfloor.errors import InputError
from groundfloor.types import BodyStates
from identification.sindy.library import LIBRARY_INPUT_NAMES, LIBRARY_STATE_NAMES
from identification.sindy.model import SindyModel, read_model_json

WINDOW_S = 5.0
MIN_TEST_WINDOWS = 4  # fewer 5 s windows on the test runs cannot support an out-of-sample verdict


def check_model_inputs(model, source: str = "model") -> None:
    """Raise InputError unless ``model`` works on ``[vx, vy, omega]`` and inputs ``[u1, u2]``."""
    variables = tuple(getattr(getattr(model, "library", None), "variables", ()))
    if variables != LIBRARY_STATE_NAMES + LIBRARY_INPUT_NAMES:
        raise InputError(f"{source}: trained on variables {list(variables)}, but a campaign provides "
                         f"states {list(LIBRARY_STATE_NAMES)} and inputs {list(LIBRARY_INPUT_NAMES)}")


def load_model(path) -> SindyModel:
    """Return the SINDy model in ``path``, checking first that it was trained on inputs ``u1, u2``."""
    path = Path(path)
    model = SindyModel.from_dict(read_model_json(path), source=str(path))  # its state and input names checked there
    check_model_inputs(model, str(path))
    return model


def check_scorable(test: Sequence[BodyStates], names: Sequence[str], window_s: float = WINDOW_S) -> None:
    """Raise InputError when the test runs cannot score a model out of sample (too few 5 s windows)."""
    if not len(test):
        raise InputError("campaign: no runs marked test, nothing to score out of sample on")
    lengths = {n: float(st.t[-1] - st.t[0]) if len(st.t) else 0.0 for st, n in zip(test, names)}
    n_win = sum(max(int((d - window_s) // (window_s / 2)) + 1, 0) for d in lengths.values() if d >= window_s)
    if n_win < MIN_TEST_WINDOWS:
        desc = ", ".join(f"{n} {d:.1f} s" for n, d in lengths.items())
        raise InputError(f"test runs too short to score out of sample: {desc} give {n_win} windows of "
                         f"{window_s:g} s (need {MIN_TEST_WINDOWS})")
