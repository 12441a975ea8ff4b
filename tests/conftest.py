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

from fxspace.data import data_root  # noqa: E402
from fxspace._compile_cache import configure_compile_cache  # noqa: E402

# ... but not in this long-lived process: it compiles well over a thousand programs, and
# jaxlib 0.10's CPU `executable.serialize()` (called to write each cache entry) segfaulted
# once in a full slow-set run (CI, stop 25). The subprocesses the tests start (CLI, apps)
# are short and keep the cache; tests/test_compile_cache.py checks it in subprocesses.
configure_compile_cache("off")


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
