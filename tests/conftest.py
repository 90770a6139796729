import numpy as np
import pytest

PRECISIONS = ["double", "long double", "quad", 237]


@pytest.fixture(params=PRECISIONS, ids=str)
def precision(request):
    return request.param


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
