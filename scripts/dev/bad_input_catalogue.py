"""The bad-input catalogue of docs/importers.md: every importer fed each kind of damaged file
(binary, not UTF-8, cut in half), with the exit status and the one error line it gets:

    python scripts/dev/bad_input_catalogue.py > catalogue.md

The cases are tests/bad_inputs.py's (tests/test_bad_input.py asserts exit 2 and one line);
the real-data cases need ../shared/realdata.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from drivee2e_data.cli import main
from tests.bad_inputs import CASES, all_cases, prepared


def run() -> None:
    print("| importer | damaged file | damage | exit | error |")
    print("|---|---|---|---|---|")
    for name, pattern, how in all_cases():
        case = CASES[name]
        with tempfile.TemporaryDirectory() as folder:
            root = Path(folder)
            source, damaged = prepared(case, pattern, how, root / "source")
            stderr = io.StringIO()
            with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
                status = main(["import", case.kind, str(source), "--out", str(root / "out")])
            lines = stderr.getvalue().strip().splitlines()
            message = lines[-1] if lines else ""
            message = message.replace(str(root / "source") + "/", "").replace(
                "drivee2e: error: ", ""
            )
            message = message.replace("|", "\\|")
            shown = str(damaged.relative_to(root / "source")) if damaged != source else damaged.name
            print(f"| {name} | `{shown}` | {how} | {status} | {message} |")


if __name__ == "__main__":
    run()
