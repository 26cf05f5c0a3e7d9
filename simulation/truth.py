"""The ``truth/`` folder of a simulated campaign: writing it and reading it back.

Nothing that processes measured data may read this (data contract); it exists to score the
pipeline against the simulator. Layout::

    CAMPAIGN/truth/
      truth.yaml                 # every true parameter, below
      runs/<run>/states.csv      # true states at every trigger pulse sent

``truth.yaml`` (SI units; UTC instants as int nanoseconds ``*_ns`` plus float seconds)::

    format: sindy-ekf-truth/1
    seed: 1                       # simulate_campaign(seed=...)
    minutes: 4.0                  # total driving time simulated (null = table 6.4, 45.4 min)
    effects: [{name: ..., value: ...}]        # the dynamics effect(s), [] for none; a form other
                                  #   than the family's default adds form: F, params: {..}
                                  #   (every parameter it acts with, drawn ones resolved)
    transform:                    # LTD800 -> AT960 (= local frame), thesis table 7.2
      translation_m: [tx, ty, tz] #   x_at960 = t + R x_ltd800 (eq. 5.1, INTERFACES.md)
      rotation_deg: [rx, ry, rz]  #   R = Rz(rz) Ry(ry) Rx(rx) (eq. 5.5)
      t_table_m: [..]             #   table 7.2's translation: x_at960 = R (x_ltd800 + t_table)
      R: [[..], [..], [..]]
    lever_arms_m: {front: [x, y, z], rear: [x, y, z]}   # body frame, table 7.1
    prism_tracker: {front: ltd800, rear: at960}
    body_origin_z_local_m: -1.25  # height of the body origin (hub centres) in the local frame
    baseline_length_m: 0.7746     # |front - rear lever arm| = c of eq. 5.25
    hubs: {front: {radius_m, radius_eq525_m}, rear: {...}}   # eccentricity (table 7.5)
    noise: {at960: {a_m, b, timing_std_s, resolution_s}, ltd800: {...}}   # table 3.2
    robot: {...}                  # the robot parameters used (simulation.robot_params.RobotParams)
    variant:                      # only for a simulator variant (simulate --variant N, N > 0):
      index: N                    #   simulation.variant.Variant.to_dict(), everything the
      robot: {...}                #   variant changes (robot terms, lateral law, motor lag,
      lateral: {form, ...}        #   process-noise spectrum, driver, tracker noise scale)
      motor_lag_s: 0.12           #   and the drawn numbers (draws); absent: Variant(), the
      noise: {form, ...}          #   simulator before variants
      driver: {...}
      tracker_noise_scale: [at960, ltd800]
      draws: {...}
    runs:
      <run>:
        split: train|test
        t0_utc_ns: int            # simulation start of the run (t = 0 of states' t_rel)
        duration_s: float         # trigger span (table 6.4, scaled)
        n_slots / n_trigger / skip_phase    # 50 Hz slots, pulses sent, skipped-slot phase
        clocks: {at960: {k, d_ns, d_s, drift_ppm}, ltd800: {...}}  # t_utc = k t_tracker + d
        at960:  {offset_s,        # mean falling-edge delay of the pulses it measured (Delta t_r,
                                  #   eqs. 5.13-5.20, table 7.4)
                 duty_mean_s, duty_jitter_std_s, lost_fraction, spurious_fraction,
                 n_lost, n_spurious, n_dropout_pulses, n_messages, dropouts_utc: [[t0, t1], ..]}
        ltd800: {n_dropout_pulses, n_messages, dropouts_utc}
        hubs:   {front: {phase_rad}, rear: {phase_rad}, n_messages}   # Phi of eq. 5.25
        joy:    {ntp_offset_s, n_messages}
        bags:   {receive_jitter_s: [lo, hi] or null,   # every message's own latency (simulate
                                  #   --receive-jitter), null: each topic received in order
                 reordered: {<topic>: n}}   # messages stored right after one with a later
                                  #   stamp (backward steps < half a trigger period)
        clock_reset:              # null, or the tracker clock restarted in this run
          {tracker, topic, t_utc_ns,        # when (UTC) its clock restarted
           message, jump_s,                 # first message on the new clock (stored order) and
                                            #   the stamp step there
           clock_after: {k, d_ns, d_s, drift_ppm}}

Counting: pulses inside a dropout count in ``n_dropout_pulses`` whatever else happened to them;
``n_lost`` / ``n_spurious`` count only events outside dropouts, so that
``n_messages = n_trigger - n_lost - n_dropout_pulses + n_spurious`` (AT960) and
``n_messages = n_trigger - n_dropout_pulses`` (LTD800).

``states.csv``: one row per pulse sent (header line, comma separated), columns
``t_utc`` (rising edge, exact to the ns), ``t_rel`` (s since t0), ``x, y, z, psi, pitch``
(body pose in the local frame, psi unwrapped), ``vx, vy, omega`` (body frame), ``u1, u2``
(inputs as the motors saw them) and ``at960_duty_s`` (this pulse's falling-edge delay).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from groundfloor.errors import InputError
from simulation.effects import Effect, effect_from_dict
from simulation.robot import TrueDynamics
from simulation.variant import Variant

FORMAT = "sindy-ekf-truth/1"
STATE_COLUMNS = ("t_utc", "t_rel", "x", "y", "z", "psi", "pitch", "vx", "vy", "omega", "u1", "u2", "at960_duty_s")
NS = 1_000_000_000


@dataclass(frozen=True)
class TrueStates:
    """True states of one run at the trigger pulses (``states.csv``)."""

    t_utc_ns: np.ndarray  # (n,) int64
    t_rel: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    psi: np.ndarray
    pitch: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    omega: np.ndarray
    u1: np.ndarray
    u2: np.ndarray
    at960_duty_s: np.ndarray

    @property
    def t_utc(self) -> np.ndarray:
        """UTC seconds (float64, ~0.24 us resolution)."""
        return self.t_utc_ns * 1e-9


@dataclass(frozen=True)
class RunTruth:
    """Every true value of one run (``truth.yaml`` runs.<name>, plus its states)."""

    name: str
    split: str
    t0_utc_ns: int
    duration_s: float
    n_slots: int
    n_trigger: int
    skip_phase: int
    clocks: dict  # tracker -> {k, d_ns, d_s, drift_ppm}
    at960: dict
    ltd800: dict
    hubs: dict
    joy: dict
    states: TrueStates | None = None
    bags: dict = field(default_factory=dict)  # receive_jitter_s, reordered per topic
    clock_reset: dict | None = None  # the tracker clock restarted in this run, if any

    def to_yaml(self) -> dict:
        """Return the run's entry of ``truth.yaml``."""
        return {
            "split": self.split, "t0_utc_ns": int(self.t0_utc_ns), "duration_s": float(self.duration_s),
            "n_slots": int(self.n_slots), "n_trigger": int(self.n_trigger), "skip_phase": int(self.skip_phase),
            "clocks": self.clocks, "at960": self.at960, "ltd800": self.ltd800, "hubs": self.hubs, "joy": self.joy,
            "bags": self.bags, "clock_reset": self.clock_reset,
        }


@dataclass(frozen=True)
class CampaignTruth:
    """Every true value of a simulated campaign (``truth/``)."""

    seed: int
    minutes: float | None
    effects: tuple  # ((name, value), ...)
    transform: dict  # translation_m, rotation_deg, t_table_m, R
    lever_arms_m: dict  # front/rear -> [x, y, z]
    body_origin_z_local_m: float
    baseline_length_m: float
    hubs: dict
    noise: dict
    robot: dict
    runs: tuple[RunTruth, ...] = field(default_factory=tuple)
    effect_specs: tuple = ()  # truth.yaml's effects entries (dicts), with form and params if any
    variant: dict | None = None  # Variant.to_dict() of a simulator variant; None: Variant()

    def effect(self) -> Effect | None:
        """Return the campaign's dynamics effect (form and parameters included), or None."""
        if self.effect_specs:
            return effect_from_dict(self.effect_specs[0])
        return Effect(*self.effects[0]) if self.effects else None

    def simulator_variant(self) -> Variant:
        """Return the simulator variant the campaign was made with (``Variant()`` without one)."""
        return Variant.from_dict(self.variant) if self.variant else Variant()

    @property
    def R_at960_ltd800(self) -> np.ndarray:
        """(3, 3) rotation of eq. 5.5."""
        return np.asarray(self.transform["R"], dtype=float)

    @property
    def t_at960_ltd800(self) -> np.ndarray:
        """(3,) translation ``t`` of eq. 5.1 (``x_at960 = t + R x_ltd800``)."""
        return np.asarray(self.transform["translation_m"], dtype=float)

    def run(self, name: str) -> RunTruth:
        """Return the truth of run ``name``."""
        for r in self.runs:
            if r.name == name:
                return r
        raise InputError(f"truth: no run {name!r}")

    def to_yaml(self) -> dict:
        """Return the content of ``truth.yaml``."""
        return {
            "format": FORMAT, "seed": int(self.seed), "minutes": self.minutes,
            "effects": list(self.effect_specs) or [{"name": n, "value": v} for n, v in self.effects],
            "transform": self.transform, "lever_arms_m": self.lever_arms_m,
            "prism_tracker": {"front": "ltd800", "rear": "at960"},
            "body_origin_z_local_m": self.body_origin_z_local_m, "baseline_length_m": self.baseline_length_m,
            "hubs": self.hubs, "noise": self.noise, "robot": self.robot,
        } | ({"variant": self.variant} if self.variant else {}) | {
            "runs": {r.name: r.to_yaml() for r in self.runs},
        }


def _plain(obj):
    """Return ``obj`` with numpy scalars and arrays turned into plain Python for YAML."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    return obj


def format_states_csv(states: TrueStates) -> str:
    """Return ``states.csv`` text; ``t_utc`` is printed from the int ns, exact to the ns."""
    sec, nsec = np.divmod(states.t_utc_ns.astype(np.int64), NS)
    table = np.column_stack([sec, nsec] + [np.asarray(getattr(states, c), float) for c in STATE_COLUMNS[1:]])
    fmt = "%d.%09d," + ",".join(["%.9f"] + ["%.9g"] * (len(STATE_COLUMNS) - 2))
    buf = io.StringIO()
    np.savetxt(buf, table, fmt=fmt, header=",".join(STATE_COLUMNS), comments="")
    return buf.getvalue()


def write_truth(campaign_dir: str | Path, truth: CampaignTruth) -> Path:
    """Write ``truth/truth.yaml`` and ``truth/runs/<run>/states.csv``; return the truth folder.

    Plain writes: the caller builds the campaign in a temporary folder that is renamed into
    place as a whole (:func:`groundfloor.files.atomic_output_dir`).
    """
    root = Path(campaign_dir) / "truth"
    for r in truth.runs:
        if r.states is not None:
            (root / "runs" / r.name).mkdir(parents=True, exist_ok=True)
            (root / "runs" / r.name / "states.csv").write_text(format_states_csv(r.states))
    root.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(_plain(truth.to_yaml()), sort_keys=False, default_flow_style=None, width=100)
    (root / "truth.yaml").write_text(text)
    return root


def _read_states(path: Path) -> TrueStates:
    with open(path) as fh:
        header = fh.readline().strip().split(",")
    if tuple(header) != STATE_COLUMNS:
        raise InputError(f"{path}: columns {header} are not {list(STATE_COLUMNS)}")
    t_text = np.loadtxt(path, delimiter=",", skiprows=1, usecols=0, dtype=str, ndmin=1)
    sec_nsec = np.char.partition(t_text, ".")
    t_ns = sec_nsec[:, 0].astype(np.int64) * NS + np.char.ljust(sec_nsec[:, 2], 9, "0").astype(np.int64)
    data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=range(1, len(STATE_COLUMNS)), ndmin=2)
    return TrueStates(t_ns, *(data[:, k] for k in range(data.shape[1])))


def read_truth(campaign_dir: str | Path, states: bool = True) -> CampaignTruth:
    """Return the :class:`CampaignTruth` stored in ``campaign_dir/truth`` (with states if asked)."""
    root = Path(campaign_dir) / "truth"
    file = root / "truth.yaml"
    if not file.is_file():
        raise InputError(f"{campaign_dir}: no truth/truth.yaml (not a simulated campaign)")
    doc = yaml.safe_load(file.read_text())
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(f"{file}: key 'format' is not {FORMAT!r}")
    runs = []
    for name, r in doc["runs"].items():
        st = _read_states(root / "runs" / name / "states.csv") if states else None
        runs.append(RunTruth(name=name, states=st, **r))
    return CampaignTruth(
        seed=doc["seed"], minutes=doc["minutes"],
        effects=tuple((e["name"], e["value"]) for e in doc["effects"]),
        transform=doc["transform"], lever_arms_m=doc["lever_arms_m"],
        body_origin_z_local_m=doc["body_origin_z_local_m"], baseline_length_m=doc["baseline_length_m"],
        hubs=doc["hubs"], noise=doc["noise"], robot=doc["robot"], runs=tuple(runs),
        effect_specs=tuple(doc["effects"]) if any("form" in e for e in doc["effects"]) else (),
        variant=doc.get("variant"),
    )


def is_simulated(campaign_dir: str | Path) -> bool:
    """Return whether ``campaign_dir`` holds the simulator's ``truth/truth.yaml``."""
    return (Path(campaign_dir) / "truth" / "truth.yaml").is_file()


def true_dynamics_of(campaign_dir: str | Path) -> TrueDynamics | None:
    """Return the simulator's true dynamics of a simulated campaign with its dynamics effect, or
    None for a measured campaign (no ``truth/``).

    The one place where the scorers (evaluation, benchmark, report) get the best any model can
    do. The dynamics are those of the campaign's simulator variant (truth/'s ``variant``:
    robot, lateral law, motor lag) with the truth's first dynamics effect in its form;
    input-side mechanisms (delay, deadband, motor lag, ...) are left to
    :meth:`TrueDynamics.motor_inputs`, never applied to the recorded inputs.
    """
    if not is_simulated(campaign_dir):
        return None
    truth = read_truth(campaign_dir, states=False)
    return TrueDynamics.of_variant(truth.simulator_variant(), truth.effect())


def campaign_summary(truth: CampaignTruth) -> dict:
    """Return the JSON summary of a simulated campaign (``simulate --json``): its truth, per run."""
    variant = {"variant": {"index": truth.variant["index"], "draws": truth.variant["draws"]}} if truth.variant else {}
    return {
        "seed": truth.seed, "minutes": truth.minutes,
        "effects": list(truth.effect_specs) or [{"name": n, "value": v} for n, v in truth.effects],
        **variant,
        "transform": {"translation_m": truth.transform["translation_m"],
                      "rotation_deg": truth.transform["rotation_deg"]},
        "lever_arms_m": truth.lever_arms_m,
        "runs": {r.name: {"split": r.split, "duration_s": r.duration_s, "n_trigger": r.n_trigger,
                          "clock": {k: {"drift_ppm": c["drift_ppm"]} for k, c in r.clocks.items()},
                          "at960_extra_offset_s": r.at960["offset_s"],
                          "at960": {k: r.at960[k] for k in ("n_messages", "n_lost", "n_spurious", "n_dropout_pulses")},
                          "ltd800": {k: r.ltd800[k] for k in ("n_messages", "n_dropout_pulses")},
                          "n_joy": r.joy["n_messages"], "n_hub": r.hubs["n_messages"],
                          "reordered": r.bags.get("reordered", {}), "clock_reset": r.clock_reset}
                 for r in truth.runs},
    }
