"""The compiled kernels where numba has nowhere to cache them (read-only install, no home)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.utility_specs.helpers import info, msg, spec_of
from utility_specs.evaluate import evaluate
from utility_specs.functions import RedImage

ROOT = Path(__file__).resolve().parents[2]
# Only the zip-file locator: a plain source file then has no cache location, as on a
# read-only root filesystem for a user without a writable home.
NO_CACHE = {**os.environ, "NUMBA_CACHE_LOCATOR_CLASSES": "ZipCacheLocator",
            "PYTHONPATH": str(ROOT)}
CHILD = """
import importlib
from tests.utility_specs.helpers import info, msg, spec_of
from utility_specs.functions import RedImage
importlib.import_module("companion.middleware._kernel")  # the optimiser's kernel too
evaluate = importlib.import_module("utility_specs.evaluate").evaluate
fn = RedImage(alpha=10.0, S=0.1, f_max=5.0, f_1=2.5)
stream = [msg(0.5 * i, 0.5 * i + 0.1, seq=i, red=(i % 3) / 4) for i in range(40)]
print(repr(evaluate(stream, spec_of(info(fn, "max")), t_end=25.0).total))
"""


def test_kernels_compile_in_process_when_numba_cannot_cache() -> None:
    pytest.importorskip("numba")
    probe = subprocess.run(
        [sys.executable, "-c", "import numba\n@numba.njit(cache=True)\ndef f(x):\n    return x\n"],
        env=NO_CACHE, capture_output=True, text=True, timeout=120, check=False,
    )
    if "no locator available" not in probe.stderr:  # what used to break the import
        pytest.skip("this numba cannot be told to have no cache location "
                    "(NUMBA_CACHE_LOCATOR_CLASSES, numba >= 0.61)")
    child = subprocess.run([sys.executable, "-c", CHILD], env=NO_CACHE, cwd=ROOT,
                           capture_output=True, text=True, timeout=300, check=False)
    assert child.returncode == 0, child.stderr
    assert child.stderr.count("numba cannot cache compiled code") == 1, child.stderr
    assert "NUMBA_CACHE_DIR" in child.stderr
    fn = RedImage(alpha=10.0, S=0.1, f_max=5.0, f_1=2.5)
    stream = [msg(0.5 * i, 0.5 * i + 0.1, seq=i, red=(i % 3) / 4) for i in range(40)]
    assert float(child.stdout) == evaluate(stream, spec_of(info(fn, "max")), t_end=25.0).total
