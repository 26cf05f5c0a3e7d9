"""The benchmark's filter settings: one YAML file over the defaults shipped with the package.

``sindy-ekf benchmark ... --config FILE`` (issue 16, item 3). The defaults live in
``sindy_ekf/data/filters.yaml`` (printed verbatim by ``sindy-ekf config --defaults``): the GNSS
profile, its seed and the outage schedule, and per estimator its process noise (or ``fit``),
initial standard deviations, gate probability, ``v_y = 0`` constraint, sensors and what it assumes
of the gyro (``imu``) and the wheel odometry (``odometry``). A user file
holds only what it changes and is merged over the defaults key by key; the defaults file is also
the schema, so a key it does not hold at that place (for that estimator) is unknown. Every value
is checked here, before any work: a bad one is a one-line :class:`InputError` naming the file and
the dotted key. :func:`load_config` returns a :class:`FilterConfig`, a tree of frozen dataclasses;
``docs/configuration.md`` describes the keys.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

from groundfloor.errors import InputError
from simulation.gnss import OUTAGE_DURATIONS_S, PROFILES, GnssProfile
from sindy_ekf.benchmark.gnss_source import RECORDED
from sindy_ekf.estimation.ekf_motion import GyroNoise, OdometryNoise

SENSORS = ("gnss", "imu", "odometry")  # what the filters fuse
MOTION_SENSORS = ("imu", "odometry")  # fused by sindy_ekf.estimation.ekf_motion and graph_motion
N_STATE = 6  # x, y, psi, vx, vy, omega
FIT = "fit"


def defaults_text() -> str:
    """Return the shipped defaults file ``sindy_ekf/data/filters.yaml``, verbatim."""
    return resources.files("sindy_ekf").joinpath("data", "filters.yaml").read_text(encoding="utf-8")


@dataclass(frozen=True)
class OutageSchedule:
    """When the benchmark drops GNSS on a test run: the outage lengths in turn, with GNSS for
    ``warmup_s`` before the first and ``recovery_s`` between two (:func:`simulation.gnss.schedule_outages`)."""

    durations_s: tuple[float, ...] = OUTAGE_DURATIONS_S
    warmup_s: float = 30.0
    recovery_s: float = 30.0


@dataclass(frozen=True)
class LateralSettings:
    """The ``v_y = 0`` pseudo-measurement of one estimator (:class:`sindy_ekf.estimation.ekf.LateralConstraint`)."""

    enabled: bool
    every: int  # grid steps between two
    vy_std_m_s: float | None  # None: fitted on the train runs (2 x RMS of their v_y)


@dataclass(frozen=True)
class EstimatorSettings:
    """One estimator's settings; ``None`` marks a setting the estimator does not have."""

    name: str
    enabled: bool
    process_noise: str | tuple  # "fit", 6 std densities per sqrt(s), or 6 rows of Q_rate
    initial_std: tuple[float, ...]  # x, y m; psi rad; vx, vy m/s; omega rad/s
    gate_prob: float | None = None  # a factor graph has no gate
    lateral: LateralSettings | None = None
    sensors: tuple[str, ...] | None = None  # dead reckoning fuses nothing by construction
    imu: GyroNoise | None = None  # what the filter assumes of the gyro, when it fuses it
    odometry: OdometryNoise | None = None  # likewise of the wheel odometry

    @property
    def P0(self) -> np.ndarray:
        """Return the initial covariance ``(6, 6)``: the squared ``initial_std`` on the diagonal."""
        return np.diag(np.asarray(self.initial_std, float) ** 2)

    @property
    def Q_rate(self) -> np.ndarray | None:
        """Return the process-noise density ``(6, 6)`` (``Q(dt) = Q_rate dt``), or None to fit it."""
        if self.process_noise == FIT:
            return None
        q = np.asarray(self.process_noise, float)
        return np.diag(q ** 2) if q.ndim == 1 else q

    @property
    def fuses_gnss(self) -> bool:
        """Return True when the estimator fuses the GNSS fixes."""
        return self.sensors is not None and "gnss" in self.sensors

    @property
    def motion_sensors(self) -> tuple[str, ...]:
        """Return the IMU / wheel-odometry sensors the estimator fuses (none: the six-state EKF)."""
        return tuple(s for s in self.sensors or () if s in MOTION_SENSORS)


@dataclass(frozen=True)
class GnssSettings:
    """Where the fixes come from and when they drop out."""

    profile: str | GnssProfile  # a name of simulation.gnss.PROFILES, "recorded", or a custom profile
    seed: int
    outages: OutageSchedule

    @property
    def profile_name(self) -> str:
        """Return the profile's name (a custom profile's own ``name``)."""
        return self.profile if isinstance(self.profile, str) else self.profile.name


@dataclass(frozen=True)
class FilterConfig:
    """The benchmark's settings (:func:`load_config`); ``source`` names the file in messages."""

    gnss: GnssSettings
    estimators: tuple[EstimatorSettings, ...]
    source: str = "defaults"

    def estimator(self, name: str) -> EstimatorSettings:
        """Return the settings of estimator ``name``."""
        for e in self.estimators:
            if e.name == name:
                return e
        raise InputError(f"{self.source}: estimators.{name}: unknown estimator "
                         f"(known: {', '.join(self.names())})")

    def names(self) -> tuple[str, ...]:
        """Return every estimator's name, in the file's order."""
        return tuple(e.name for e in self.estimators)

    def enabled(self) -> tuple[str, ...]:
        """Return the names of the enabled estimators."""
        return tuple(e.name for e in self.estimators if e.enabled)

    def with_overrides(self, profile: str | None = None, seed: int | None = None,
                       estimators: Sequence[str] | None = None, outages: OutageSchedule | None = None
                       ) -> FilterConfig:
        """Return the settings with what the command line gave instead of the file's: ``profile``
        and ``seed`` of the GNSS, ``estimators`` (exactly these enabled), the ``outages``."""
        gnss = self.gnss
        gnss = dataclasses.replace(gnss, profile=gnss.profile if profile is None else profile,
                                   seed=gnss.seed if seed is None else int(seed),
                                   outages=gnss.outages if outages is None else outages)
        ests = self.estimators
        if estimators is not None:
            wanted = set(estimators)
            ests = tuple(dataclasses.replace(e, enabled=e.name in wanted) for e in ests)
        return dataclasses.replace(self, gnss=gnss, estimators=ests)

    def to_dict(self) -> dict:
        """Return the settings as the YAML file's mapping (every key; a file of it loads back equal)."""
        p = self.gnss.profile
        profile = p if isinstance(p, str) else {**dataclasses.asdict(p), "outlier_m": list(p.outlier_m)}
        o = self.gnss.outages
        return {"gnss": {"profile": profile, "seed": self.gnss.seed,
                         "outages": {"warmup_s": o.warmup_s, "recovery_s": o.recovery_s,
                                     "durations_s": list(o.durations_s)}},
                "estimators": {e.name: _estimator_dict(e) for e in self.estimators}}


def _estimator_dict(e: EstimatorSettings) -> dict:
    """Return one estimator's settings as its mapping in the file."""
    pn = e.process_noise
    out: dict[str, Any] = {"enabled": e.enabled,
                           "process_noise": pn if isinstance(pn, str) else _nested_list(pn),
                           "initial_std": list(e.initial_std)}
    if e.gate_prob is not None:
        out["gate_prob"] = e.gate_prob
    if e.lateral is not None:
        std = e.lateral.vy_std_m_s
        out["lateral"] = {"enabled": e.lateral.enabled, "every": e.lateral.every,
                          "vy_std_m_s": FIT if std is None else std}
    if e.sensors is not None:
        out["sensors"] = list(e.sensors)
    for key, noise in (("imu", e.imu), ("odometry", e.odometry)):
        if noise is not None:
            out[key] = dataclasses.asdict(noise)
    return out


def _nested_list(v):
    """Return nested tuples as nested lists."""
    return [_nested_list(x) for x in v] if isinstance(v, tuple) else v


# -- reading ----------------------------------------------------------------------------------

class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (it keeps the last silently)."""


def _construct_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    """Return the mapping of ``node``; a ConstructorError at the second of two equal keys."""
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"key {key!r} given twice", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _parse(text: str, source: str) -> Any:
    """Return the YAML document of ``text``; InputError naming ``source`` and the line if malformed."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(f"{source}: not valid YAML{where}: {problem}") from None


def _read(path: str | Path) -> str:
    """Return the text of the file at ``path``; InputError naming it when it cannot be read."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{path}: config file not found")
    if p.is_dir():
        raise InputError(f"{path}: config file is a folder")
    try:
        return p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the config file ({exc})") from None


def _defaults() -> dict:
    """Return the shipped defaults as a mapping."""
    return _parse(defaults_text(), "filters.yaml (defaults)")


def load_config(path: str | Path | None = None) -> FilterConfig:
    """Return the settings of the file at ``path`` merged over the defaults (None: the defaults).

    Raises
    ------
    InputError
        One line naming the file and the dotted key: a missing or malformed file, an unknown key,
        estimator or sensor, a value of the wrong type or out of range.
    """
    if path is None:
        return config_from_dict({}, "defaults")
    return config_from_dict(_parse(_read(path), str(path)), str(path))


def config_from_dict(data: Any, source: str) -> FilterConfig:
    """Return the settings of the mapping ``data`` (a parsed file) merged over the defaults;
    ``source`` names it in errors (see :func:`load_config`)."""
    data = {} if data is None else data  # an empty file changes nothing
    merged = _merge(_defaults(), data, "", source)
    return _build(merged, source)


def _merge(default: dict, user: Any, where: str, source: str) -> dict:
    """Return ``user`` merged over ``default`` key by key; unknown keys are an InputError."""
    if not isinstance(user, dict):
        raise InputError(f"{source}: {where or 'top level'}: expected a mapping, got {user!r}")
    out = dict(default)
    for k, v in user.items():
        if not isinstance(k, str):  # YAML 1.1 reads on/off/yes/no as booleans, numbers as numbers
            raise InputError(f"{source}: {where or 'top level'}: key {k!r} is not a name (quote it)")
        key = f"{where}.{k}" if where else k
        if k not in default:
            if where == "estimators":
                raise InputError(f"{source}: {key}: unknown estimator (known: {', '.join(default)})")
            owner = f" ({where.split('.')[-1]} takes {', '.join(default)})" if where.startswith("estimators.") else \
                f" (known: {', '.join(default)})"
            raise InputError(f"{source}: {key}: unknown key{owner}")
        out[k] = _merge(default[k], v, key, source) if isinstance(default[k], dict) else v
    return out


# -- checking ---------------------------------------------------------------------------------

def _fail(source: str, key: str, expected: str, value: Any) -> InputError:
    """Return the one-line error for ``value`` at ``key``."""
    return InputError(f"{source}: {key}: expected {expected}, got {value!r}")


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)


def _number(v: Any, source: str, key: str, expected: str, ok) -> float:
    """Return ``v`` as a float if it is a finite number for which ``ok`` holds."""
    if not (_is_number(v) and ok(v)):
        raise _fail(source, key, expected, v)
    return float(v)


def _integer(v: Any, source: str, key: str, expected: str, ok) -> int:
    """Return ``v`` if it is an integer (not a bool) for which ``ok`` holds."""
    if not (isinstance(v, int) and not isinstance(v, bool) and ok(v)):
        raise _fail(source, key, expected, v)
    return int(v)


def _boolean(v: Any, source: str, key: str) -> bool:
    if not isinstance(v, bool):
        raise _fail(source, key, "true or false", v)
    return v


def _numbers(v: Any, n: int | None, source: str, key: str, expected: str, ok) -> tuple[float, ...]:
    """Return ``v`` as a tuple of floats: a list of ``n`` (any number if None) numbers passing ``ok``."""
    if not (isinstance(v, list) and (n is None or len(v) == n) and all(_is_number(x) and ok(x) for x in v)):
        raise _fail(source, key, expected, v)
    return tuple(float(x) for x in v)


def _process_noise(v: Any, source: str, key: str) -> str | tuple:
    """Return ``fit``, 6 std densities, or the 6 rows of a symmetric positive definite Q_rate."""
    expected = ("fit, 6 standard deviation densities > 0 or a 6 x 6 symmetric positive definite "
                "matrix")
    if v == FIT:
        return FIT
    if isinstance(v, list) and v and all(isinstance(r, list) for r in v):
        if len(v) != N_STATE or any(len(r) != N_STATE or not all(map(_is_number, r)) for r in v):
            raise _fail(source, key, expected, v)
        rows = tuple(tuple(float(x) for x in r) for r in v)
        q = np.array(rows)
        if not np.allclose(q, q.T, rtol=1e-12, atol=0.0) or np.linalg.eigvalsh(0.5 * (q + q.T)).min() <= 0:
            raise InputError(f"{source}: {key}: the 6 x 6 matrix is not symmetric positive definite")
        return rows
    return _numbers(v, N_STATE, source, key, expected, lambda x: x > 0)


def _sensors(v: Any, source: str, key: str) -> tuple[str, ...]:
    """Return the sensor names; an unknown one, or one listed twice, is an error."""
    if not (isinstance(v, list) and all(isinstance(s, str) for s in v)):
        raise _fail(source, key, f"a list of sensor names ({', '.join(SENSORS)})", v)
    for s in v:
        if s not in SENSORS:
            raise InputError(f"{source}: {key}: unknown sensor {s!r} (known: {', '.join(SENSORS)})")
    if len(set(v)) != len(v):
        raise InputError(f"{source}: {key}: a sensor is listed twice: {v!r}")
    return tuple(v)


def _lateral(v: dict, source: str, key: str) -> LateralSettings:
    std = v["vy_std_m_s"]
    return LateralSettings(_boolean(v["enabled"], source, f"{key}.enabled"),
                           _integer(v["every"], source, f"{key}.every", "an integer >= 1", lambda x: x >= 1),
                           None if std == FIT else _number(std, source, f"{key}.vy_std_m_s", "fit or a number > 0",
                                                           lambda x: x > 0))


_NOISE = {"imu": GyroNoise, "odometry": OdometryNoise}  # the sensor-noise mappings of an estimator


def _noise(kind: str, v: dict, source: str, key: str) -> GyroNoise | OdometryNoise:
    """Return the assumed noise of sensor ``kind`` from its mapping; every value a number > 0 (the
    odometry's relative ``scale_std`` >= 0: 0 says wheels that do not slip)."""
    kw = {}
    for f in dataclasses.fields(_NOISE[kind]):
        kw[f.name] = (_number(v[f.name], source, f"{key}.{f.name}", "a number >= 0", lambda x: x >= 0)
                      if f.name == "scale_std" else
                      _number(v[f.name], source, f"{key}.{f.name}", "a number > 0", lambda x: x > 0))
    return _NOISE[kind](**kw)


def _estimator(name: str, v: dict, source: str) -> EstimatorSettings:
    key = f"estimators.{name}"
    return EstimatorSettings(
        name, _boolean(v["enabled"], source, f"{key}.enabled"),
        _process_noise(v["process_noise"], source, f"{key}.process_noise"),
        _numbers(v["initial_std"], N_STATE, source, f"{key}.initial_std", "6 numbers > 0", lambda x: x > 0),
        gate_prob=(_number(v["gate_prob"], source, f"{key}.gate_prob", "a number in (0, 1]", lambda x: 0 < x <= 1)
                   if "gate_prob" in v else None),
        lateral=_lateral(v["lateral"], source, f"{key}.lateral") if "lateral" in v else None,
        sensors=_sensors(v["sensors"], source, f"{key}.sensors") if "sensors" in v else None,
        **{kind: _noise(kind, v[kind], source, f"{key}.{kind}") for kind in _NOISE if kind in v})


_PROFILE_CHECKS = {  # GnssProfile field -> (expected, test); name and outlier_m apart
    "rate_hz": ("a number > 0", lambda x: x > 0),
    "std_m": ("a number >= 0", lambda x: x >= 0),
    "std_up_m": ("a number >= 0", lambda x: x >= 0),
    "latency_s": ("a number >= 0", lambda x: x >= 0),
    "latency_jitter_s": ("a number >= 0", lambda x: x >= 0),
    "bias_std_m": ("a number >= 0", lambda x: x >= 0),
    "bias_tau_s": ("a number > 0", lambda x: x > 0),
    "outlier_prob": ("a number in [0, 1]", lambda x: 0 <= x <= 1),
}


def _profile(v: Any, source: str) -> str | GnssProfile:
    """Return a profile name or a custom :class:`simulation.gnss.GnssProfile` from its fields."""
    key = "gnss.profile"
    if isinstance(v, str):
        if v not in PROFILES and v != RECORDED:
            raise InputError(f"{source}: {key}: unknown GNSS profile {v!r} "
                             f"(choose from {', '.join([*PROFILES, RECORDED])} or give a custom profile's fields)")
        return v
    if not isinstance(v, dict):
        raise _fail(source, key, "a profile name or a mapping of GnssProfile fields", v)
    fields = {f.name: f for f in dataclasses.fields(GnssProfile)}
    for k in v:
        if k not in fields:
            raise InputError(f"{source}: {key}.{k}: unknown key (a GnssProfile has {', '.join(fields)})")
    missing = [n for n, f in fields.items()
               if n != "name" and f.default is dataclasses.MISSING and n not in v]
    if missing:
        raise InputError(f"{source}: {key}.{missing[0]}: missing (a custom profile needs "
                         f"{', '.join(n for n in fields if n != 'name' and fields[n].default is dataclasses.MISSING)})")
    kw: dict[str, Any] = {"name": v.get("name", "custom")}
    if not isinstance(kw["name"], str) or not kw["name"]:
        raise _fail(source, f"{key}.name", "a non-empty text", kw["name"])
    for n, (expected, ok) in _PROFILE_CHECKS.items():
        if n in v:
            kw[n] = _number(v[n], source, f"{key}.{n}", expected, ok)
    if "outlier_m" in v:
        lo_hi = _numbers(v["outlier_m"], 2, source, f"{key}.outlier_m", "[low, high] with 0 <= low <= high",
                         lambda x: x >= 0)
        if lo_hi[0] > lo_hi[1]:
            raise _fail(source, f"{key}.outlier_m", "[low, high] with 0 <= low <= high", v["outlier_m"])
        kw["outlier_m"] = lo_hi
    return GnssProfile(**kw)


def _build(d: dict, source: str) -> FilterConfig:
    """Return the :class:`FilterConfig` of the merged mapping ``d``, every value checked."""
    g, o = d["gnss"], d["gnss"]["outages"]
    outages = OutageSchedule(
        _numbers(o["durations_s"], None, source, "gnss.outages.durations_s", "a list of numbers > 0",
                 lambda x: x > 0),
        _number(o["warmup_s"], source, "gnss.outages.warmup_s", "a number >= 0", lambda x: x >= 0),
        _number(o["recovery_s"], source, "gnss.outages.recovery_s", "a number >= 0", lambda x: x >= 0))
    gnss = GnssSettings(_profile(g["profile"], source),
                        _integer(g["seed"], source, "gnss.seed", "an integer >= 0", lambda x: x >= 0), outages)
    ests = tuple(_estimator(name, v, source) for name, v in d["estimators"].items())
    return FilterConfig(gnss, ests, source)

