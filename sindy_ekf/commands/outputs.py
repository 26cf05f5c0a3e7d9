"""Output paths of a command checked before its work starts (issue 14, item 4).

A command that fails on its output after minutes of work, or leaves half its output behind,
wastes the work: every ``--json`` file and every ``--plots`` folder (and folder-like ``--out``)
is checked first (:func:`groundfloor.files.check_output_file`, :func:`check_output_folder`).
"""

from __future__ import annotations

from groundfloor.files import check_output_file, check_output_folder


def check_outputs(args, files: tuple[str, ...] = ("json",), folders: tuple[str, ...] = ("plots",)) -> None:
    """Raise InputError naming the option unless each given output of ``args`` can be written.

    ``files`` and ``folders`` name attributes of ``args`` (``json``, ``plots``, ``out``); a
    missing attribute or a None value is skipped.
    """
    for name in files:
        value = getattr(args, name, None)
        if value is not None:
            check_output_file(value, f"--{name}")
    for name in folders:
        value = getattr(args, name, None)
        if value is not None:
            check_output_folder(value, f"--{name}")
