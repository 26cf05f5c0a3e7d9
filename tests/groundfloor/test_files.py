"""Output checks: a file that cannot be written is named before any work is done."""

from __future__ import annotations

import pytest

from groundfloor.errors import InputError
from groundfloor.files import check_output_file


def test_a_writable_file_name_passes(tmp_path):
    assert check_output_file(tmp_path / "new" / "model.json", "--out") == tmp_path / "new" / "model.json"


def test_a_folder_is_not_a_file_name(tmp_path):
    with pytest.raises(InputError, match=r"--out .*: is a folder, expected a file name"):
        check_output_file(tmp_path, "--out")


def test_a_file_below_a_regular_file_names_the_blocker(tmp_path):
    blocker = tmp_path / "blocker"
    blocker.write_text("a regular file")
    with pytest.raises(InputError, match=rf"--json .*: cannot be written, {blocker} is a file, not a folder"):
        check_output_file(blocker / "deeper" / "x.json", "--json")
