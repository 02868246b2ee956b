"""``uav-sitl fleet --summary-json FILE`` that cannot be written.

Before: a parent that was a file let the whole mission run, then ended it with
"uav-sitl fleet: [Errno 17] File exists", exit 2, and no summary printed. Now a destination
that is bad when the options are read is a usage error before anything starts
(tests/integration/test_cli_bad_input.py), and one that breaks during the run is a one-line
warning after the summary, pointing at RUN/summary.json.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

FLEET = Path(sys.executable).parent / "uav-sitl"


@pytest.mark.timeout(180)
def test_a_summary_json_that_breaks_during_the_run_is_a_warning_after_the_summary(
        tmp_path: Path) -> None:
    if not FLEET.exists():
        pytest.skip(f"{FLEET} missing: install the project in this venv")
    run_dir, folder = tmp_path / "run", tmp_path / "copies"
    folder.mkdir()
    proc = subprocess.Popen([str(FLEET), "fleet", "--drones", "1", "--duration", "4",
                             "--out", str(run_dir), "--summary-json", str(folder / "s.json")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert proc.stdout is not None
        seen = []
        for line in proc.stdout:
            seen.append(line)
            if line.startswith("mission started"):
                break
        folder.rmdir()
        folder.write_text("now a file\n")  # the copy's folder is gone
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    out = "".join(seen) + out
    assert "Traceback" not in err, err[-3000:]
    assert proc.returncode == 0, err[-3000:]
    assert f"data: {run_dir}" in out, out[-3000:]  # the summary was printed
    warnings = [line for line in err.splitlines() if "--summary-json" in line]
    assert len(warnings) == 1, err[-3000:]
    assert warnings[0].startswith("uav-sitl fleet: warning: cannot write --summary-json")
    assert warnings[0].endswith(f"the summary is in {run_dir / 'summary.json'}")
    assert json.loads((run_dir / "summary.json").read_text())["drones"]
