"""Time ``simulate_campaign`` on the full default campaign (table 6.4, 45.4 min); bag sizes.

Usage: ``.venv/bin/python bench/bench_simulate.py [--minutes M] [--seed N] [--no-write]``.
Target (issue 2): at most 60 s on 2 cores, robot dynamics included. Writes
``bench/results/simulate.md`` (unless ``--no-write``) with the figures and this command.
The stages are timed by wrapping the library functions (robot dynamics, message
serialisation, bag writing); the rest is the measurement chain and truth/.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from simulation import bags, robot  # noqa: E402
from simulation import campaign as campaign_mod  # noqa: E402


def _timed(module, name: str, acc: dict, key: str) -> None:
    """Replace ``module.name`` by a wrapper adding its wall time to ``acc[key]``."""
    fn = getattr(module, name)

    @functools.wraps(fn)
    def wrapper(*a, **k):
        t, c = time.perf_counter(), time.process_time()
        try:
            return fn(*a, **k)
        finally:
            wall, cpu = acc.get(key, (0.0, 0.0))
            acc[key] = (wall + time.perf_counter() - t, cpu + time.process_time() - c)

    setattr(module, name, wrapper)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()

    acc: dict = {}
    _timed(robot, "simulate_run", acc, "robot dynamics (simulate_run)")
    for name in ("serialize_time_reference", "serialize_point_stamped", "serialize_joy", "serialize_joint_state"):
        _timed(bags, name, acc, "message serialisation (bulk numpy, checked against serialize_ros1)")
    _timed(bags, "write_bag", acc, "bag writing (rosbags Writer)")
    _timed(campaign_mod.truth_io, "write_truth", acc, "truth/ writing")

    with tempfile.TemporaryDirectory(prefix="bench-sim-") as tmp:
        out = Path(tmp) / "campaign"
        t0, c0 = time.perf_counter(), time.process_time()
        truth = campaign_mod.simulate_campaign(out, seed=args.seed, minutes=args.minutes)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        sizes = {kind: sum(p.stat().st_size for p in out.glob(f"runs/*/{kind}_*.bag")) for kind in ("husky", "server")}
        truth_size = sum(p.stat().st_size for p in (out / "truth").rglob("*") if p.is_file())
        n_msgs = sum(sum(bags.count_messages(d).values()) for d in (out / "runs").iterdir())
    minutes = sum(r.duration_s for r in truth.runs) / 60
    chain = (wall - sum(w for w, _ in acc.values()), cpu - sum(c for _, c in acc.values()))
    cmd = "/work/main/.venv/bin/python bench/bench_simulate.py" + (
        f" --minutes {args.minutes:g}" if args.minutes is not None else "")
    lines = [
        "## simulate: full default campaign",
        "",
        f"Command: `{cmd}` (seed {args.seed}; Python {platform.python_version()}, {os.cpu_count()} cores, "
        f"load average {os.getloadavg()[0]:.1f} at the end: other jobs shared the cores)",
        "",
        "| quantity | wall | CPU (this process) |",
        "|---|---|---|",
        f"| driving time simulated | {minutes:.1f} min in {len(truth.runs)} runs | |",
        f"| `simulate_campaign`, total | **{wall:.1f} s** (target <= 60 s) | {cpu:.1f} s |",
        *[f"| of which {k} | {w:.1f} s | {c:.1f} s |" for k, (w, c) in acc.items()],
        f"| of which measurement chain (clocks, edges, hubs, noise) and the rest | {chain[0]:.1f} s | {chain[1]:.1f} s |",
        f"| messages written | {n_msgs:,} | |",
        f"| bag size, robot bags (`husky_*.bag`) | {sizes['husky'] / 2**20:.1f} MiB | |",
        f"| bag size, tracker-server bags (`server_*.bag`) | {sizes['server'] / 2**20:.1f} MiB | |",
        f"| truth/ size | {truth_size / 2**20:.1f} MiB | |",
        "",
        "Wall time includes waiting for the 2 cores shared with other jobs; CPU time is this "
        "process's own (single-threaded) work.",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    if not args.no_write:
        (ROOT / "bench" / "results").mkdir(exist_ok=True)
        (ROOT / "bench" / "results" / "simulate.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
