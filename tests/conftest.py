import os
import sys

# tests/helpers.py is imported as `helpers` from every test folder (importlib import mode)
sys.path.insert(0, os.path.dirname(__file__))

os.environ.setdefault("FXSPACE_QUIET", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import jax  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

matplotlib.use("Agg")
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

from fxspace.data import data_root  # noqa: E402


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
