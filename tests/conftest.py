"""Shared fixtures. BLAS threads are pinned to 1: see shared/reference/measured-pitfalls.md."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

# Property-based fuzzing (tests/test_fuzz_*.py): a bounded profile for CI by default,
# HYPOTHESIS_PROFILE=long for a longer run by hand (docs/file-format.md, "Fuzzing").
try:
    from hypothesis import HealthCheck, settings

    settings.register_profile("ci", max_examples=60, deadline=None, derandomize=True,
                              suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
    settings.register_profile("long", max_examples=3000, deadline=None,
                              suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
    settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
except ImportError:  # hypothesis is a dev extra; the fuzz tests skip without it
    pass


import importlib.util  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402
from types import ModuleType  # noqa: E402

import pytest  # noqa: E402


def load_script(name: str) -> ModuleType:
    """``scripts/NAME.py`` imported as a module (once per session; dataclasses look it up in sys.modules)."""
    key = f"fgloc_script_{name}"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, Path(__file__).resolve().parents[1] / "scripts" / f"{name}.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]


@pytest.fixture(scope="session")
def field_time() -> ModuleType:
    """``scripts/field_time.py`` (the field-time plan's benchmark), imported."""
    return load_script("field_time")
