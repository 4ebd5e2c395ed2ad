"""Random rays for the march-kernel tests, the march's inputs along them, and the twins'
agreement on them (shared by test_kernels, test_emission_grid and test_scatter_grid); the
path tracer's twins' agreement (``path_twins``, shared by the path tests)."""
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


def march_inputs(rng, media, lights, pre, n, half_width, step, **optional):
    """kernels.MarchInputs for ``n`` of ``downward_rays`` (``half_width`` m, spread 0.2,
    t0 up to 2 m) through the prepared ``media`` lit by ``lights`` with the precompute
    ``pre``'s fields, no world light, a step of ``step`` m; ``optional``: the record's
    optional fields (emissions, bricks, channels ...)."""
    from mpp_render.kernels import MarchInputs
    from mpp_render.march import pack_lights
    o, d, t0, t1 = downward_rays(rng, n, half_width, 0.2, 2.0)
    return MarchInputs(o, d, t0, t1, np.ones(n), rng.integers(0, 2**32, n, dtype=np.uint32),
                       pre.fields, [m.w2i for m in media], [m.sigma_s for m in media],
                       [m.sigma_t for m in media], [m.g for m in media],
                       [m.threshold for m in media], [m.voxel_size for m in media],
                       pack_lights(lights, pre.layout), -1, step, 0.01, 1e10, **optional)


def path_twins(inp):
    """(numpy, C) deposits of the path tracer on ``inp`` (paths.PathInputs), asserted to
    hold light and to agree to 1e-9 of the largest."""
    from mpp_render import kernels
    from mpp_render.paths import trace_paths_np
    a = trace_paths_np(inp)
    b = kernels.trace_paths(inp, threads=2)
    assert a.sum() > 0.0
    assert np.abs(a - b).max() <= 1e-9 * np.abs(a).max()
    return a, b
