"""Results are frozen dataclasses (STYLE.md): a stage's output cannot be changed by its consumer.

Every dataclass of the numeric packages is checked, not a list kept by hand, so a new result
type is covered when it appears; the few mutable ones are named here with the reason.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil

import pytest

PACKAGES = ("groundfloor", "simulation", "identification", "sindy_ekf.estimation", "sindy_ekf.benchmark",
            "sindy_ekf.diagnose")
MUTABLE = {  # class -> why it is not frozen
    "identification.sindy.model.SindyModel": "a fitted model: pysindy-style attributes set while fitting",
    "sindy_ekf.diagnose.extend.ExtendedModel": "a fitted model like SindyModel",
    "identification.preprocessing.io_bags._Topic": "private accumulator of one topic's messages while reading",
}


def _dataclasses():
    for pkg_name in PACKAGES:
        pkg = importlib.import_module(pkg_name)
        names = [pkg_name] + [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg_name + ".")]
        for name in names:
            module = importlib.import_module(name)
            for obj in vars(module).values():
                if isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__module__ == name:
                    yield f"{name}.{obj.__qualname__}", obj


ALL = dict(_dataclasses())


def test_the_walk_finds_the_result_types():
    for name in ("sindy_ekf.estimation.ekf.EkfResult", "identification.sindy.evaluate.Windows",
                 "sindy_ekf.diagnose.rank.RankedCause", "sindy_ekf.benchmark.health.RunStatus"):
        assert name in ALL


@pytest.mark.parametrize("name", sorted(set(ALL) - set(MUTABLE)))
def test_every_result_dataclass_is_frozen(name):
    cls = ALL[name]
    assert cls.__dataclass_params__.frozen, f"{name} is a mutable dataclass"
    fields = dataclasses.fields(cls)
    if fields:  # assigning a field of an instance fails (built without __init__: no arguments needed)
        obj = object.__new__(cls)
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(obj, fields[0].name, None)
