import os
from pathlib import Path

import numpy as np
import pytest

# heyoka keeps the code it compiles in an on-disk cache (an SQLite file shared by every program of the user) and
# checks that file whole (PRAGMA quick_check) the first time a process compiles: with the 8.5 GB it had grown to
# here, 2.1 s of CPU for each process of the suite that compiles (the two workers, the Dask worker), against 0.07 s
# for the suite's own cache (170 MB after one run). Set here, before any test imports heyoka, so the workers and
# every child process inherit it; a HEYOKA_CACHE_DIR set by the user is kept. Outside the checkout, so that a fresh
# clone finds the code compiled by the last run (compiling the suite's integrators afresh costs ~80 s of CPU).
SUITE_HEYOKA_CACHE = str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "lieseries"
                         / "heyoka-tests")
os.environ.setdefault("HEYOKA_CACHE_DIR", SUITE_HEYOKA_CACHE)

PRECISIONS = ["double", "long double", "quad", 237]


@pytest.fixture(params=PRECISIONS, ids=str)
def precision(request):
    return request.param


@pytest.fixture(scope="session", autouse=True)
def heyoka_cache_bound():
    """The suite's own heyoka cache keeps its most recently used 512 MiB: the check on opening reads what it keeps
    (measured: 0.3 s of CPU for each process of the suite that compiles with 1 GiB kept, 0.14 s with 512 MiB), and
    a run of the default suite uses 130 MiB of it (629 compiled functions)."""
    import heyoka

    if str(heyoka.llvm_state.get_diskcache_path()) == SUITE_HEYOKA_CACHE:
        heyoka.llvm_state.set_diskcache_limit(2**29)


def rng(seed=0):
    return np.random.default_rng(seed)


@pytest.fixture(params=["gmpy", "int"])
def bigint(request):
    """Run the test with each big-integer backend of the fixed-point jets (gmpy2's mpz, and Python ints: what an
    installation without gmpy2 uses, forced by LIESERIES_BIGINT=int)."""
    from lieseries.lie import fixed

    before = fixed.backend()
    fixed.set_backend(request.param)
    yield fixed.backend()
    fixed.set_backend(before)
