"""Importing the optimiser does not import scikit-learn (the adaptive constraint's model), and
the lazily imported names are the real ones (the package's docstring promises both)."""

from __future__ import annotations

import subprocess
import sys


def test_the_optimiser_imports_without_scikit_learn() -> None:
    code = ("import sys, companion.middleware, companion.middleware.constraints; "
            "assert 'sklearn' not in sys.modules, 'sklearn imported'; "
            "print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_lazy_names_resolve_to_their_modules() -> None:
    import companion.middleware.constraints as constraints
    from companion.middleware.constraints import adaptive, aimd, registry

    assert constraints.make_constraint is registry.make_constraint
    assert constraints.CONSTRAINTS is registry.CONSTRAINTS
    assert constraints.AdaptiveConstraint is adaptive.AdaptiveConstraint
    assert constraints.AimdConstraint is aimd.AimdConstraint
