"""Stamps of a run's bags in the order the bags store them, read with rosbags' own reader and
deserialiser (independent of the project's fast byte path), for the tests of issue 14."""

from __future__ import annotations

from pathlib import Path

import numpy as np

HALF_PERIOD_S = 0.01  # half of the simulator's 20 ms trigger period


def stored_stamps(run_dir: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Return ``topic -> (stamps s, bag times s)`` in stored order (bag time, ties in file order);
    the trigger's stamp is ``time_ref``, the others' ``header.stamp``."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out: dict[str, list] = {}
    with AnyReader(sorted(Path(run_dir).glob("*.bag")), default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        for conn, t_bag, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = msg.time_ref if conn.topic == "/rpi/trigger" else msg.header.stamp
            out.setdefault(conn.topic, []).append((stamp.sec * 1_000_000_000 + stamp.nanosec, t_bag))
    return {k: (np.array([s for s, _ in v]) * 1e-9, np.array([t for _, t in v]) * 1e-9) for k, v in out.items()}


def backward_steps(stamps: np.ndarray) -> tuple[int, int]:
    """Return ``(reorderings, resets)``: backward steps shorter and longer than half a period."""
    step = np.diff(stamps)
    return int(np.sum((step < 0) & (step >= -HALF_PERIOD_S))), int(np.sum(step < -HALF_PERIOD_S))
