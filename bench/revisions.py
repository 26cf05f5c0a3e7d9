"""A revision of the checkout exported beside it, for the before/after bench scripts."""

from __future__ import annotations

import subprocess
from pathlib import Path


def export_revision(root: Path, rev: str, dest: Path) -> Path:
    """Write the tree of ``rev`` of the git checkout ``root`` into the new folder ``dest``; return ``dest``."""
    dest.mkdir()
    archive = subprocess.run(["git", "-C", str(root), "archive", rev], check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)
    return dest
