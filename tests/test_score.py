"""R1, the one formula every ranking uses."""

import numpy as np

from smorphi_rl.score import r1


def test_r1_of_one_result_and_of_arrays():
    assert r1(97.0, 66, 1.0, 0.1) == 97.0 - 6.6
    out = r1(np.array([97.0, 90.0]), np.array([66, 50]), 1.0, 0.1)
    assert out.dtype == np.float64 and np.allclose(out, [90.4, 85.0])
