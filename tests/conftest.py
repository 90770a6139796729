import numpy as np
import pytest

PRECISIONS = ["double", "long double", "quad", 237]


@pytest.fixture(params=PRECISIONS, ids=str)
def precision(request):
    return request.param


def rng(seed=0):
    return np.random.default_rng(seed)
