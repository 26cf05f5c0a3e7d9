"""A structural variant of the simulator: the robot, its actuators, noise, driver and trackers.

:class:`Variant` bundles every structural choice the simulator makes beyond the effects: model
B's coefficients and limiter bounds (:class:`simulation.robot_params.RobotParams`), the lateral
law (:mod:`simulation.lateral`), a first-order motor lag, the process-noise spectrum
(:mod:`simulation.process_noise`), the driver's style and joystick clock
(:class:`simulation.driver.DriverParams`) and the laser trackers' point noise
(:mod:`simulation.measurement`). ``Variant()`` (index 0) is the simulator as it was before
variants existed; :func:`simulation.variants.draw_variant` draws the others from their index.

A variant is plain data and round-trips through :meth:`Variant.to_dict` (the ``variant``
section of truth/, :mod:`simulation.truth`), so that the true dynamics of a campaign are rebuilt
from what truth/ says, never from the drawing code of the day.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

from groundfloor.errors import InputError
from simulation.driver import DriverParams
from simulation.lateral import LateralLaw
from simulation.measurement import AT960, LTD800, TrackerSpec
from simulation.process_noise import ProcessNoise
from simulation.robot_params import RobotParams


@dataclass(frozen=True)
class Variant:
    """Structural choices of one simulator variant (index 0: the simulator before variants)."""

    index: int = 0
    robot: RobotParams = field(default_factory=RobotParams)
    lateral: LateralLaw = field(default_factory=LateralLaw)
    motor_lag_s: float = 0.0  # first-order lag of both motors (0: none)
    noise: ProcessNoise = field(default_factory=ProcessNoise)
    driver: DriverParams = field(default_factory=DriverParams)
    tracker_noise_scale: tuple = (1.0, 1.0)  # AT960, LTD800 point noise relative to table 3.2
    draws: tuple = ()  # ((name, value), ...): the drawn numbers, for truth/ and the bench

    @property
    def is_default(self) -> bool:
        """True for the simulator before variants (nothing of it differs from ``Variant()``)."""
        return self == Variant()

    def trackers(self) -> dict[str, TrackerSpec]:
        """Return the trackers' noise and timing figures with this variant's point noise."""
        return {spec.name: replace(spec, noise_a_m=spec.noise_a_m * k, noise_b=spec.noise_b * k)
                if k != 1.0 else spec for spec, k in zip((AT960, LTD800), self.tracker_noise_scale)}

    def to_dict(self) -> dict:
        """Return every field as plain values (truth/'s ``variant`` section, robot terms included)."""
        return {"index": int(self.index), "robot": _plain(asdict(self.robot)), "lateral": self.lateral.to_dict(),
                "motor_lag_s": float(self.motor_lag_s), "noise": self.noise.to_dict(),
                "driver": _plain(asdict(self.driver)), "tracker_noise_scale": [float(k) for k in self.tracker_noise_scale],
                "draws": {k: _plain(v) for k, v in self.draws}}

    @classmethod
    def from_dict(cls, doc: dict) -> Variant:
        """Return the variant written by :meth:`to_dict`."""
        return cls(index=int(doc["index"]), robot=_dataclass_from(RobotParams, doc["robot"]),
                   lateral=LateralLaw.from_dict(doc["lateral"]), motor_lag_s=float(doc["motor_lag_s"]),
                   noise=ProcessNoise.from_dict(doc["noise"]), driver=_dataclass_from(DriverParams, doc["driver"]),
                   tracker_noise_scale=tuple(float(k) for k in doc["tracker_noise_scale"]),
                   draws=tuple((k, _frozen(v)) for k, v in doc.get("draws", {}).items()))


def _plain(obj):
    """Return ``obj`` with tuples as lists (YAML-friendly, numbers as float or str as is)."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    return obj


def _frozen(obj):
    """Return ``obj`` with lists as tuples (hashable, as the frozen dataclasses hold them)."""
    return tuple(_frozen(v) for v in obj) if isinstance(obj, (list, tuple)) else obj


def _dataclass_from(cls, doc: dict):
    """Return ``cls(**doc)`` with lists turned back into tuples; unknown keys are an error."""
    names = {f.name for f in fields(cls)}
    unknown = set(doc) - names
    if unknown:
        raise InputError(f"variant: {cls.__name__} has no fields {sorted(unknown)}")
    return cls(**{k: _frozen(v) for k, v in doc.items()})
