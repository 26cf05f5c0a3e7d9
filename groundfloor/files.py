"""Atomic file and folder writes, and output checks: never leave half a result behind.

Every writer in the project goes through these: a file is written to a temporary name in the
same folder and renamed (``os.replace`` is atomic on POSIX), a folder is built under a
temporary name and renamed into place at the end.
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np

from groundfloor.errors import InputError


def _umask() -> int:
    """Return the process umask (reading it means setting it, so set it back at once)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file and a rename; return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        # mkstemp creates 0600; a result file gets the usual permissions.
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path


def atomic_write_json(path: str | os.PathLike, obj) -> Path:
    """Write ``obj`` as indented JSON to ``path`` atomically; return the path."""
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=False) + "\n")


def check_output_dir(path: str | os.PathLike, force: bool = False) -> Path:
    """Return ``path`` as a Path if it may be (re)written, else raise InputError.

    A missing folder is fine; an existing non-empty one needs ``force``; the parent must be
    writable.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: output exists and is not a folder")
    if path.exists() and any(path.iterdir()) and not force:
        raise InputError(f"{path}: output folder is not empty (use --force to replace it)")
    parent = path.resolve().parent
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not os.access(probe, os.W_OK):
        raise InputError(f"{path}: output folder is not writable")
    return path


def check_output_file(path: str | os.PathLike, option: str) -> Path:
    """Return ``path`` as a Path if a file can be written there, else raise InputError naming the culprit.

    Checked before any work: the path must not be a folder, its nearest existing ancestor must
    be a writable folder (not a regular file). ``option`` names the command-line option
    (``--out``) in the message.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder, expected a file name")
    _check_writable_ancestor(path, path.parent if str(path.parent) else Path("."), option, "written")
    return path


def check_output_folder(path: str | os.PathLike, option: str) -> Path:
    """Return ``path`` as a Path if files can be written into it, else raise InputError naming the culprit.

    Checked before any work, for folders whose files are (re)written one by one (``--plots``,
    ``benchmark --out``): the path may exist as a folder but not as a file, its nearest existing
    ancestor must be a writable folder.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {path}: is a file, expected a folder")
    _check_writable_ancestor(path, path, option, "created")
    return path


def _check_writable_ancestor(path: Path, start: Path, option: str, verb: str) -> None:
    """Raise InputError unless the nearest existing ancestor of ``start`` (itself included) is a writable folder."""
    probe = start
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{option} {path}: cannot be {verb}, {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK):
        raise InputError(f"{option} {path}: folder {probe} is not writable")


def check_outputs(args, files: tuple[str, ...] = ("json",), folders: tuple[str, ...] = ("plots",)) -> None:
    """Raise InputError naming the option unless each output of a command's ``args`` can be written.

    Issue 14: a command that fails on its output after its work wastes the work, so every
    ``--json`` file and ``--plots`` folder (and a folder-like ``--out``) is checked first.
    ``files`` and ``folders`` name attributes of ``args``; a missing one or None is skipped.
    """
    for name in files:
        value = getattr(args, name, None)
        if value is not None:
            check_output_file(value, f"--{name}")
    for name in folders:
        value = getattr(args, name, None)
        if value is not None:
            check_output_folder(value, f"--{name}")


@contextlib.contextmanager
def atomic_output_dir(path: str | os.PathLike, force: bool = False) -> Iterator[Path]:
    """Yield a temporary sibling folder to fill; on success it replaces ``path``.

    On any exception the temporary folder is removed and ``path`` is left as it was.
    """
    path = check_output_dir(path, force=force)
    path.resolve().parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.resolve().parent))
    # mkdtemp creates 0700; the finished folder gets the usual permissions.
    os.chmod(tmp, 0o777 & ~_umask())
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if path.exists():
        shutil.rmtree(path)
    os.replace(tmp, path)


def csv_header(path: str | os.PathLike) -> list[str]:
    """Return the column names on the first line of a CSV file, stripped, a UTF-8 byte-order mark
    (what spreadsheet exports write first) dropped, and quotes around a name (R's ``write.csv``
    quotes every one) taken off."""
    with open(path, encoding="utf-8-sig") as fh:
        line = fh.readline().strip()
    return [h.strip() for h in next(csv.reader([line]), [""])] or [""]


def missing_column(path: str | os.PathLike, column: str, header: list[str]) -> InputError:
    """Return the one-line error of a required CSV column missing, saying so when the file is not
    comma-separated (a semicolon or tab export: the data contract's files use commas)."""
    line = ",".join(header)
    sep = next((s for s in (";", "\t") if len(header) == 1 and s in line), None)
    hint = f"; columns separated by {'tabs' if sep == chr(9) else repr(sep)}, the data contract's CSV files use commas" \
        if sep else ""
    return InputError(f"{path}: required column '{column}' missing (header: {line}){hint}")


def unlisted_runs(root: str | os.PathLike, listed) -> list[str]:
    """Return the folders under ``root/runs`` that ``campaign.yaml`` does not list (hidden ones
    aside), sorted: a run copied in without its entry would otherwise be left out unsaid.

    A part ``<run>.k`` of a listed run counts as listed (its folder is the run's own)."""
    names = set(listed)
    runs = Path(root) / "runs"
    if not runs.is_dir():
        return []
    return sorted(p.name for p in runs.iterdir()
                  if p.is_dir() and not p.name.startswith(".") and p.name not in names)


def no_numbers(path: str | os.PathLike, header: list[str], column: str, values: np.ndarray) -> InputError | None:
    """Return the one-line error of a CSV column that holds text where numbers belong (every value
    read as NaN, the first one not empty or ``nan``: a date and time, units written beside the
    numbers), or None. Without it each such row would be dropped as a NaN row and the file read as
    empty."""
    values = np.asarray(values, dtype=float)
    if not values.size or not np.isnan(values).all() or column not in header:
        return None
    with open(path, encoding="utf-8-sig") as fh:
        fh.readline()
        fields = fh.readline().rstrip("\r\n").split(",")
    k = header.index(column)
    first = fields[k].strip() if k < len(fields) else ""
    if first.lower() in ("", "nan"):
        return None
    hint = "; a date and time? the data contract's t is in seconds (e.g. since the epoch)" \
        if column == "t" and any(ch in first for ch in "-:") else ""
    return InputError(f"{path}: column {column} holds no numbers (first value {first!r}){hint}")
