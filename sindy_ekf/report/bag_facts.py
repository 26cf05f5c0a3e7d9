"""What reading a run's bags found, in words, from the preprocess JSON of its runs.

Shared by the ``preprocess`` command's summary and the report's synchronisation table, so that
both say it the same way (the keys are written by
:func:`identification.preprocessing.preprocess.reading_json`).
"""

from __future__ import annotations


def bag_words(run: dict) -> str:
    """Return the facts of reading one run's bags in a few words, or ``"-"``."""
    words = [f"{n} {what}" for key, what in (("reordered", "reordered"), ("nan_points_dropped", "NaN"))
             if (n := sum((run.get(key) or {}).values()))]
    if run.get("truncated"):
        words.append("truncated")
    if run.get("part_of"):
        words.append(f"part of {run['part_of']}")
    return ", ".join(words) or "-"


def bag_notes(runs: dict[str, dict]) -> list[str]:
    """Return one line per topic stored out of stamp order or timed by its bag time, truncated bag,
    clock reset and part dropped, each run cut at clock resets named once."""
    lines, seen = [], set()
    for name, r in runs.items():
        stored = ", ".join(f"{t} {n}" for t, n in (r.get("reordered") or {}).items() if n)
        if stored:
            lines.append(f"{name}: messages stored out of stamp order, sorted: {stored}")
        unset = ", ".join(f"{t} {n}" for t, n in (r.get("unstamped_receive_time") or {}).items() if n)
        if unset:
            lines.append(f"{name}: header stamps never set (zero), timed by their bag time: {unset}")
        source = r.get("part_of") or name
        if source in seen:
            continue
        seen.add(source)
        lines += [f"{source}: bag {t['bag']} truncated ({t['reason']}): {t['messages']} messages read "
                  "before the damage and used" if t["messages"] else
                  f"{source}: bag {t['bag']} unreadable ({t['reason']}): left out, the run read from its other bags"
                  for t in r.get("truncated") or []]
        for c in r.get("clock_resets") or []:
            lines.append(f"{source}: topic {c['topic']}: clock reset at message {c['message']} (stamps "
                         f"jump {c['jump_s']:+.6f} s): run cut there")
        if r.get("part_of"):
            parts = [n for n, q in runs.items() if q.get("part_of") == source]
            lines.append(f"{source}: processed as {', '.join(parts)}")
        lines += [f"{source}: part dropped: {why}" for why in r.get("parts_dropped") or []]
    return lines
