"""Random rays for the march-kernel tests, and the twins' agreement on them (shared by
test_kernels, test_emission_grid and test_scatter_grid)."""
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


def march_twins(inputs):
    """(numpy, C) results of the march kernel on ``inputs`` (kernels.MarchInputs), asserted
    finite and equal to 1e-4 relative, field by field."""
    from mpp_render import kernels
    from mpp_render.kernels import MarchResult
    a = kernels.march(inputs, backend="numpy")
    b = kernels.march(inputs, backend="c")
    for x, y, name in zip(a, b, MarchResult._fields):
        assert np.all(np.isfinite(y)), name
        assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6)), name
    return a, b
