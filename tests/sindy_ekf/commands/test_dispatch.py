"""Git-style dispatch: ``sindy-ekf --help`` lists every command from a static table without
importing any command's library; running a command imports its module only."""

from __future__ import annotations

import json
import subprocess
import sys

from sindy_ekf import cli
from tests.support import REPO

HEAVY = ("matplotlib", "gtsam", "scipy", "identification", "simulation", "sindy_ekf.stages",
         "sindy_ekf.benchmark", "sindy_ekf.diagnose", "sindy_ekf.report")


def modules_after(argv: list[str]) -> set[str]:
    """Return the modules loaded by ``cli.main(argv)`` in a fresh interpreter (help exits early)."""
    code = ("import json, sys\nfrom sindy_ekf import cli\ntry:\n    cli.main(%r)\nexcept SystemExit:\n    pass\n"
            "print(json.dumps(sorted(sys.modules)))" % argv)
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    return set(json.loads(done.stdout.splitlines()[-1]))


def test_the_table_lists_every_command_module():
    on_disk = {p.stem for p in (REPO / "sindy_ekf" / "commands").glob("*.py") if p.stem != "__init__"}
    assert set(cli.COMMANDS) == on_disk
    parser, modules = cli.build_parser()
    assert set(modules) == on_disk
    help_text = parser.format_help()
    assert all(name in help_text for name in cli.COMMANDS)


def test_help_imports_no_command_and_no_library():
    loaded = modules_after(["--help"])
    assert not {m for m in loaded if m.startswith("sindy_ekf.commands.")}
    assert not {m for m in loaded for h in HEAVY if m == h or m.startswith(h + ".")}


def test_a_command_imports_its_own_module_only():
    loaded = modules_after(["simulate", "--help"])
    assert {m for m in loaded if m.startswith("sindy_ekf.commands.")} == {"sindy_ekf.commands.simulate"}
    assert cli.command_of(["--quiet", "evaluate", "c", "--model", "m.json"]) == "evaluate"
