"""How a bench script hands over its result: the markdown file written atomically, then shown."""

from __future__ import annotations

from pathlib import Path

from groundfloor.files import atomic_write_text


def publish(path: Path, lines: list[str]) -> None:
    """Write ``lines`` as one markdown file at ``path`` (atomically: never half a result) and print it."""
    text = "\n".join(lines) + "\n"
    atomic_write_text(path, text)
    print(text)
