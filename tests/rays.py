"""Random rays for the march-kernel tests (shared by test_kernels and test_emission_grid)."""
import numpy as np


def downward_rays(rng, n, half_width, spread, t0_hi):
    """``n`` rays from the plane z = 4 m (x, y uniform in +-``half_width`` m) heading down,
    tilted by a normal of sd ``spread`` per axis, with t0 uniform in [0.5, ``t0_hi``] m and
    t1 = t0 + up to 6 m: (origins, unit directions, t0, t1)."""
    o = rng.uniform(-half_width, half_width, (n, 3))
    o[:, 2] = 4.0
    d = rng.normal(size=(n, 3)) * [spread, spread, 0.0]
    d[:, 2] = -1
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t0 = rng.uniform(0.5, t0_hi, n)
    t1 = t0 + rng.uniform(0, 6, n)
    return o, d, t0, t1
