import atexit
import os
import shutil
import sys
import tempfile

# tests/helpers.py is imported as `helpers` from every test folder (importlib import mode)
sys.path.insert(0, os.path.dirname(__file__))

os.environ.setdefault("FXSPACE_QUIET", "1")
# one fresh persistent compilation cache per test session (shared with the subprocesses the
# tests start), never the user's folder
if "FXSPACE_COMPILE_CACHE" not in os.environ:
    _cache = tempfile.mkdtemp(prefix="fxspace-tests-jax-cache-")
    os.environ["FXSPACE_COMPILE_CACHE"] = _cache
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)
os.environ.setdefault("MPLBACKEND", "Agg")

import jax  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

matplotlib.use("Agg")
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

from fxspace._compile_cache import configure_compile_cache  # noqa: E402
from fxspace.data import data_root  # noqa: E402

# ... but not in this long-lived process, which compiles a few thousand programs: writing
# each one costs a serialisation, and the subprocesses the tests start (CLI, apps) are the
# ones that gain from it (tests/test_compile_cache.py checks the cache in subprocesses).
configure_compile_cache("off")


_MAPS_HIGH = 25000


def _memory_maps() -> int:
    try:
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)
    except OSError:  # not Linux
        return 0


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs at the end of a test module once the process holds many.

    XLA:CPU maps about 19 memory regions per loaded executable and keeps them while the
    executable is cached; a process that holds a few thousand programs reaches the kernel's
    ``vm.max_map_count`` (65530) and the next compilation — or the serialisation of a
    compilation-cache entry — segfaults inside XLA (CI, stop 25: the slow set, 180 tests
    in). Past `_MAPS_HIGH` maps the caches are cleared, which unmaps them; a module that
    alone gets near the limit fails here with the count instead of crashing the run."""
    yield
    if _memory_maps() > _MAPS_HIGH:
        jax.clear_caches()
        n = _memory_maps()
        assert n < 50000, f"{n} memory maps after clearing JAX's caches (limit 65530): a leak"


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture
def key():
    return jax.random.PRNGKey(0)


@pytest.fixture(scope="session")
def data_dir():
    root = data_root()
    if root is None:
        pytest.skip("real capture data absent: set FXSPACE_DATA or provide ../shared/data")
    return root


_DURATIONS = os.environ.get("FXSPACE_TEST_DURATIONS")


def pytest_runtest_logreport(report):
    """With ``FXSPACE_TEST_DURATIONS=FILE``, append each test's call time as it finishes (to
    size the default set while a long run is still going)."""
    if _DURATIONS and report.when == "call":
        with open(_DURATIONS, "a") as f:
            f.write(f"{report.duration:.2f} {report.outcome} {report.nodeid}\n")


# Tests measured as long on the 2-core machine (call time > 3 s under load) run with the
# slow set (`-m slow`, which CI runs too), so the README's `python -m pytest` stays short.
# One node id a line in tests/slow_tests.txt; regenerate it from FXSPACE_TEST_DURATIONS.
_SLOW_LIST = os.path.join(os.path.dirname(__file__), "slow_tests.txt")


def pytest_collection_modifyitems(config, items):
    try:
        with open(_SLOW_LIST) as f:
            slow = {line.strip() for line in f if line.strip() and not line.startswith("#")}
    except OSError:
        return
    for item in items:
        if item.nodeid in slow:
            item.add_marker(pytest.mark.slow)
