"""Every numpy/CasADi twin of the package (registry in ``twins.py``): equal values at random points
(1e-12 relative to the output's magnitude) and CasADi Jacobians equal to central finite differences."""

import numpy as np
import pytest

from twins import TWINS, check_twin


def test_registry_names_are_unique():
    names = [c.name for c in TWINS]
    assert len(names) == len(set(names)), sorted(n for n in names if names.count(n) > 1)


@pytest.mark.parametrize("case", TWINS, ids=str)
def test_twin(case):
    check_twin(case, np.random.default_rng(case.seed))
