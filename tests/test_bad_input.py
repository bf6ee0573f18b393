"""Every importer meets damaged files (binary, not UTF-8, cut in half) with one error line naming
the file, exit status 2, and nothing written."""

from pathlib import Path

import pytest
from conftest import REALDATA

from drivee2e_data.cli import main
from tests.bad_inputs import CASES, all_cases, prepared


@pytest.mark.parametrize("name, pattern, how", all_cases())
def test_a_damaged_file_is_one_error_line_exit_2(name, pattern, how, tmp_path: Path, capsys):
    case = CASES[name]
    if case.needs_realdata and not REALDATA.is_dir():
        pytest.skip("../shared/realdata is absent")
    source, damaged = prepared(case, pattern, how, tmp_path / "source")
    out = tmp_path / "out"
    assert main(["import", case.kind, str(source), "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1, error
    assert error[0].startswith("drivee2e: error: ") and damaged.name in error[0], error[0]
    assert not out.exists()
