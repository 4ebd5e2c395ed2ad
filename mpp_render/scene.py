"""Plain, bpy-free description of what is rendered.

The Blender glue (``mpp_render.blender``) fills these dataclasses from the evaluated
depsgraph; everything after that (precompute, march, passes) reads only them.

Conventions used throughout the numeric core:

* World space is Blender's: metres, right-handed, +Z up.
* Directions called ``direction`` are unit vectors along which light *propagates*.
* Colours are linear scene-referred RGB (Rec.709 primaries), as float64 arrays of shape (3,).
* Coefficients are in 1/m; light powers in watts, sun irradiance in W/m^2, radiance in
  W/(m^2 sr) -- the same units Cycles uses, so images compare one to one.
* Images are (height, width, channels) with row 0 at the *top*.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np


@dataclass
class Camera:
    """A pinhole (PERSP) or orthographic (ORTHO) camera.

    ``cam_to_world`` is a 4x4 rigid transform (rotation + translation, no scale): the camera
    looks down its local -Z with +Y up, as in Blender.  ``plane`` = (xmin, xmax, ymin, ymax)
    bounds the image in camera space: for PERSP on the plane z = -1 (dimensionless, so
    tangents of the half angles), for ORTHO in metres.  ``clip_start``/``clip_end`` are planar
    distances along the view axis in metres, as in Cycles.

    Depth of field (Cycles' thin lens): ``aperture`` the lens radius in metres (0: a pinhole),
    ``focus_distance`` the distance of the plane in focus along the view axis (m),
    ``blades`` the aperture's sides (below 3: a disc), ``blade_rotation`` (radians),
    ``aperture_ratio`` the anamorphic squeeze (the aperture's x divided by it).

    ``projection`` 'PANO': a panoramic camera as Cycles' (camera.panorama_directions), its
    ``panorama`` a dict: ``type`` ('EQUIRECTANGULAR', 'FISHEYE_EQUIDISTANT',
    'FISHEYE_EQUISOLID', 'FISHEYE_LENS_POLYNOMIAL' or 'MIRRORBALL'), ``fov`` (radians),
    ``lens`` and ``sensor`` (width, height) in mm, ``longitude``/``latitude`` (min, max)
    radians, ``polynomial`` (k0..k4); its clipping is spherical (distance from the camera).
    """

    projection: str
    cam_to_world: np.ndarray
    width: int
    height: int
    plane: tuple
    clip_start: float = 0.1
    clip_end: float = 1000.0
    aperture: float = 0.0
    focus_distance: float = 10.0
    blades: int = 0
    blade_rotation: float = 0.0
    aperture_ratio: float = 1.0
    panorama: Optional[dict] = None


@dataclass
class Light:
    """One light in Cycles' units.

    ``kind``: 'POINT', 'SPOT', 'SUN' or 'AREA'.
    ``strength``: RGB; for POINT/SPOT/AREA the emitted power in W (colour x temperature colour
    x energy x 2**exposure), for SUN the irradiance in W/m^2 on a plane facing the sun.
    ``position``: metres (unused for SUN).  ``direction``: unit vector of propagation (the
    light's local -Z in world space).  ``matrix``: the light object's 4x4 world matrix (spot
    cone frame with non-uniform scale, area-light axes and size).
    ``radius``: metres, sphere radius of POINT and SPOT.  ``spot_size``: full cone angle in
    radians; ``spot_blend`` in [0, 1].  ``angle``: SUN angular diameter in radians.
    ``shape``: area shape 'SQUARE', 'RECTANGLE', 'DISK' or 'ELLIPSE'; ``size_x``/``size_y``:
    metres in the light's local X/Y (before the object's scale, which ``matrix`` carries).
    ``normalize``: area power is spread over the area (Cycles' default).
    ``indirect``: the light is itself scattered light (bounce.py's light from a surface): its
    first scattering in the media counts as multiple scattering (Cycles' Volume Indirect),
    not single.
    """

    kind: str
    name: str
    strength: np.ndarray
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -1.0]))
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))
    radius: float = 0.0
    spot_size: float = np.pi / 4
    spot_blend: float = 0.15
    angle: float = 0.0
    shape: str = "SQUARE"
    size_x: float = 1.0
    size_y: float = 1.0
    normalize: bool = True
    indirect: bool = False


@dataclass
class Medium:
    """A participating medium on a voxel grid.

    ``density``: float32 array (nx, ny, nz), dimensionless, >= 0, finite.  Values sit at
    integer index points (voxel centres at integer ijk, as in OpenVDB) and are interpolated
    trilinearly; outside the array the density is 0.
    ``index_to_world``: 4x4 affine map from index space (i, j, k, 1) to world metres.
    ``sigma_s`` / ``sigma_a``: RGB scattering / absorption coefficient in 1/m per unit density,
    so sigma_s(x) = sigma_s * density(x).  ``g``: Henyey-Greenstein anisotropy in (-1, 1).
    ``emission``: RGB emitted radiance per metre (W/(m^3 sr)), not scaled by density, as in
    Cycles' Principled Volume; given off wherever the density is > 0; zero for most media.
    ``emission_grid``: None, or float32 (nx, ny, nz, 3) emitted radiance per metre
    (W/(m^3 sr)) at the same index points as ``density`` (e.g. blackbody emission from a
    temperature grid, blackbody.py), interpolated trilinearly and given off wherever it is
    non-zero (not gated by density: Cycles emits wherever the shader is evaluated); added to
    ``emission``.  NaN, inf and negative values are set to 0 with a warning.
    ``scatter_grid``: None, or float32 (nx, ny, nz, 3), dimensionless: per voxel the factor on
    ``sigma_s`` where the scattering colour varies in space (a node tree into a Principled
    Volume's Color), so sigma_s(x) = sigma_s * scatter_grid(x) * density(x), both grids
    interpolated trilinearly; ``sigma_s`` is then the density-weighted mean.  The extinction
    stays ``sigma_t`` * density(x) unless ``extinction_grid`` is given.  NaN, inf and negative
    values are set to 0 with a warning.
    ``extinction_grid``: None, or float32 (nx, ny, nz, 3), dimensionless: per voxel the factor
    on ``sigma_t`` where the extinction's colour varies in space (a coloured Absorption Color
    field, a Volume Scatter's coloured Color field), so sigma_t(x) = sigma_t *
    extinction_grid(x) * density(x) per channel; NaN, inf and negative values are set to 0
    with a warning.  The scattering is ``scatter_grid``'s, so the absorption is what is left.
    A medium with one is interpolated like a grid (no sharp surface).
    ``source``: 'MESH' (a mesh volume: one density with a sharp surface), 'MESH_FIELD' (a
    mesh volume whose density a shader node tree varies: interpolated like a grid), 'VDB',
    'FLUID' or 'WORLD' (for messages and tests).  A 'WORLD'
    medium held by ``World.volume`` fills all space homogeneously: only its coefficients and
    ``emission`` are read (``density`` and ``index_to_world`` are placeholders); the
    renderer bounds it (worldfog.py).
    """

    name: str
    density: np.ndarray
    index_to_world: np.ndarray
    sigma_s: np.ndarray
    sigma_a: np.ndarray
    g: float = 0.0
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    source: str = "VDB"
    emission_grid: Optional[np.ndarray] = None
    scatter_grid: Optional[np.ndarray] = None
    extinction_grid: Optional[np.ndarray] = None

    @property
    def sigma_t(self) -> np.ndarray:
        return self.sigma_s + self.sigma_a


@dataclass
class Surface:
    """An opaque triangle mesh: stops camera rays and shadows the media.  Shaded as Cycles'
    Principled BSDF (surfaces.py); the defaults are a plain Lambertian 0.8 grey, Cycles' look
    for a mesh without material.

    ``vertices``: float64 (N, 3) world metres; ``triangles``: int64 (M, 3) vertex indices.
    ``name``: the object's name.  ``emission``: RGB emitted radiance W/(m^2 sr).
    ``base_color``: RGB, dimensionless: the diffuse albedo under the specular layer, and the
    reflectance at normal incidence of the metal (Principled 'Base Color').
    ``specular``: the dielectric specular layer's reflectance at normal incidence F0,
    dimensionless in [0, 1]: ((IOR - 1) / (IOR + 1))^2 x 2 x 'Specular IOR Level' (0.04 for
    IOR 1.5 at level 0.5); 0 means no specular layer (a Diffuse BSDF).  An IOR below 1 acts as
    its reciprocal.  ``roughness``: 'Roughness' in [0, 1] of the specular layer and of the
    metal (GGX alpha = roughness^2).  ``metallic``: 'Metallic' in [0, 1].
    ``specular_tint``: RGB 'Specular Tint': scales the dielectric F0 and is the metal's
    F82 edge tint.
    ``coat_weight`` (>= 0), ``coat_roughness`` ([0, 1]), ``coat_ior`` (>= 1), ``coat_tint``
    (RGB): the Principled coat layer; ``coat_weight`` 0 means none.
    ``diffuse_roughness``: 'Diffuse Roughness' in [0, 1] (0: Lambert, above: Oren-Nayar as
    Cycles' energy-preserving variant).  ``multiscatter``: the node's distribution is
    'Multiscatter GGX' (energy compensation of the GGX lobes) rather than 'GGX'.
    ``weight``: the BSDF's share in [0, 1] of the material (Mix Shader factors; the rest is
    emission or shaders we leave out), scaling all reflected light.
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    base_color: np.ndarray = field(default_factory=lambda: np.full(3, 0.8))
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    specular: float = 0.0
    roughness: float = 0.5
    metallic: float = 0.0
    specular_tint: np.ndarray = field(default_factory=lambda: np.ones(3))
    coat_weight: float = 0.0
    coat_roughness: float = 0.03
    coat_ior: float = 1.5
    coat_tint: np.ndarray = field(default_factory=lambda: np.ones(3))
    diffuse_roughness: float = 0.0
    multiscatter: bool = True
    weight: float = 1.0


@dataclass
class World:
    """Constant background radiance ``color`` (RGB, W/(m^2 sr)), seen by rays that leave the
    scene and lighting the media from every direction.

    ``volume``: None, or the world's Volume shader as a homogeneous medium that fills all
    space, as Cycles' world volume (a Medium with source 'WORLD'; coefficients in 1/m,
    emission in W/(m^3 sr)).  In every colour channel where its extinction is > 0 it
    attenuates the background and sun lights completely (they are infinitely far away)."""

    color: np.ndarray = field(default_factory=lambda: np.zeros(3))
    volume: Optional[Medium] = None


@dataclass(frozen=True)
class Tuning:
    """The method's speed and exactness knobs, at the values measured best (docs/method.md);
    tests and benchmarks compare variants (``dataclasses.replace``).  They travel with the
    Settings through the precompute and the march.

    ``skip_min_voxels``: grids from which optical_depth walks the media's bricks (below it a
    grid sits in the cache and walking the bricks costs more than it saves; the result is
    the same either way).  ``spot_cull``: the pyramid's cells a spot's cone misses are 0
    without a read (the same result, faster).  ``refine``: how much finer than the walk's
    lattice a mesh volume's forward peak and exact first flights are computed
    (precompute.source.fine_stride; 1: the walk's).  ``first_flights``: a mesh volume's first
    flights computed exactly where they mostly leave it (firstflight.py); ``exact_flights``
    how many (1 or 2).  ``flatten``: a mesh volume's light pyramids summed over levels and
    lights once for the march (precompute.flatten.flatten_levels; the exact first flights join only that
    level).  ``skip_empty``: the march skips super-steps where every medium is empty (the
    same result, faster).  ``adapt_tau``: the march's longer steps in thin media (the
    density majorant's optical depth per step within it; 0: off).  ``tile``: the largest
    tile side in pixels.  ``surface_gathers``: directions per camera sample through which a
    surface gathers the sky, the volumes' light and the other surfaces' (surfaces.shade); 4
    took p_fog_spot_shafts' single scattering from 0.194 to 0.079 at 16 spp (its pillars are
    lit by the spot-lit ground, its ground by the beam's fog) for 25-40 % more render time in
    scenes with a ground.  ``tile_rays``, ``tile_rays_most``, ``tile_samples``: camera rays
    per tile (all its samples), as many as hold ``tile_samples`` march samples at the pilot's
    samples per ray (its surface gathers' counted in), within [tile_rays, tile_rays_most]
    (tiles.tile_rays; tile_rays without a pilot, and the pilot's own chunks): each tile's
    Python work is a fixed cost beside the kernels' per sample (cloud_vdb at 1920x1080, at
    the cap of 16384 rays a tile, marched 1.14x faster than at 4096; the six
    noisiest scenes' single scattering within the seeds' scatter over 4 seeds:
    docs/adaptive.md), and a tile of dear rays stays short for Esc.
    ``adaptive_first``: with adaptive sampling, the samples a pixel
    gets before its own noise is judged (at least 2: a variance needs two); with the pilot,
    only the pixels it marks get them, the others stop at one.  ``pilot_stride``: the
    pilot of adaptive sampling looks at one pixel in each square of this side (pixels);
    ``pilot_samples`` samples each (pilot.py; at least 2): at 8 and 4, a sixteenth of a
    one-sample frame's rays (4: a quarter, and the suite's errors within the seeds' scatter
    of 8's; docs/adaptive.md); 0: no pilot, every pixel takes ``adaptive_first`` samples and
    the threshold is in Cycles' unit (sqrt of the pixel's luminance).  ``step_voxels``: the march step where
    Step Size is 0, in the finest voxel's sides (1.0 marched cloud_vdb with 0.58 of the
    samples but took the suite's single scattering from 0.029 to 0.054 at the 90th
    percentile: p_point_in_plume 0.000 -> 0.090, p_sphere_thick 0.020 -> 0.039,
    p_spot_in_fogbox 0.006 -> 0.028; docs/performance.md).
    ``gather_moments``: where surfaces gather the media's light, the traced paths also keep
    their moments, which the gathers read towards the surface (paths.py, "Moments");
    False: the gathers read the camera's M (benchmarks/gathers.py compares the two).
    ``roulette``: the march's Russian roulette below this transmittance (a ray goes on with
    probability T / roulette, T scaled up to keep the mean; 0: every ray marches on until
    T < 1e-6): unbiased, with fewer steps behind nearly opaque media.
    ``gather_step``: the surfaces' gathers march with steps this many times the camera's.
    ``disc_exact``: within this many lamp radii of a point or spot light with a radius (half
    diagonals of an area light, lights.extent_radius), the optical depth to the sampled disc
    (emitter) point is corrected by marching that point's path and the centre's through the
    media (kernels_np.disc_correction; 0: the centre's depth
    stretched alone, exact only in a homogeneous medium); only where the media within it are
    uneven (media.disc_reaches).  Beyond it the disc subtends under atan(1/2) = 27 degrees.
    p_point_in_plume's single scattering: 0.138 at 0, within the references' noise at 1.5
    and above (bias -0.0057 at 1.5, -0.0049 at 2, -0.0024 at 4, -0.0017 at 8); its march
    1.22x slower at 2 (1.41x with steps of one voxel), 1.84x at 4 (960x540, side by side).
    ``disc_voxels``: that reach is at least this many of the finest voxel of the media: the
    disc points' paths part over most of their length whatever the lamp's size, and a lamp
    of 0.05-0.15 m in smoke needs the same reach as one of 0.3 m (hold-out variants of
    p_point_in_plume: a 0.1 m lamp's single scattering 0.121 at 2 radii, 0.038 at 16 voxels;
    docs/method.md §10); 16 is what 2 radii of the public plume's 0.3 m lamp are in its
    voxels, so that scene is unchanged.
    ``disc_fold_stride``: beyond that reach the march reads the stretched centre's depth
    plus the lamp's disc's depth change D, which the precompute makes on a lattice of every
    this-many-th voxel (precompute/discdepth.py; 0: none, the stretched depth alone, Jensen-
    dark where the smoke is uneven across the disc).  The hold-out v_plume_lamp2_r3 (a 0.3 m
    lamp in the plume's smoke, single scattering): 0.117 (bias -0.025) without, 0.0596 /
    0.0584 / 0.0586 at strides 4 / 2 / 1 when the fold was the field's own depth; the
    precompute 0.07 / 0.15 / 1.7 s more: the stride is not what is left.
    ``disc_fold_nodes``: the disc's nodes per lattice point (Gauss-Legendre in the squared
    radius, lights.disc_transmittance): in a density step at the lamp (tests/test_disc_fold.py)
    8 nodes missed the disc's mean by up to 10 %, 16 by about 1 %.  An area light's emitter
    takes about sqrt(nodes) per axis, at least lights.AREA_EXACT_NODES (4 x 4 at 16).
    ``guided_gathers``: the share of a surface's gathers drawn about the lamps that a medium
    surrounds rather than cosine-weighted, the two weighed by the balance heuristic
    (gathers.py; 0: all cosine-weighted).  Round a lamp in fog or smoke its glow on a ground
    is peaked towards the lamp: at 0.5, p_fog_point's per-sample noise (4 gathers, 160x90,
    4 seeds) 0.078 -> 0.056 of the frame's mean, the hold-out v_smoke_lamp's single
    scattering 0.076 -> 0.046 (docs/guided_gathers.md).
    ``smooth_step_voxels``: the march step where Step Size is 0 and the light in the media
    changes no faster than their voxels (media.smooth_light: density grids only, no spot, no
    lamp within ``disc_voxels`` voxels of them), in the finest voxel's sides; a jittered point
    per step stays unbiased, and what a longer step costs is noise where the integrand
    changes within it, which these scenes do not have.  1.0 left the suite's scenes of this
    kind as they were (cloud_vdb, p_backlit_vdb, p_noise_cloud, smoke_plume; single
    scattering within 0.0001, full renders within 0.0003) with about 0.6 of the march
    samples (docs/performance.md).
    ``smooth_step_tau``: that longer step is cut to this optical depth in the densest voxel
    (never below ``step_voxels``): one point per step reads the transmittance across it as
    e^-tau(u), whose mean over the step exceeds the step's transmittance by sinh(d/2)/(d/2) - 1
    = d^2/24 for tau changing by d across it, 1 % at d = 0.5, the worst case being a step
    from empty to the densest voxel (p_dragon, 1.2 of optical depth in a voxel, scored 0.041
    against 0.040 at a voxel a step, and keeps its half voxel).
    ``path_deposits``: the traced paths' tentative collisions, each a deposit, per lattice
    spacing h at least (paths.py: the rate mu = max(majorant, path_deposits / h)).  Where the
    medium is thinner than that, the deposits are the paths' cost, and fewer of them buy more
    paths in the same time: at 0.5 and 3 000 000 paths against 1.0 and 2 000 000 (the same
    precompute time within 5 %), two seeds each, rel_rmse_4 on eight mesh-volume scenes fell
    on five (colored_sphere 0.0128 -> 0.0116, p_backlit_slab 0.0344 -> 0.0292,
    p_overlap 0.0124 -> 0.0115, p_chromatic_box 0.0138 -> 0.0110, p_sphere_g95
    0.096 -> 0.077) and held on three (p_sphere_gneg, p_point_in_cube, slab_isotropic);
    the first four of the eight chose it, the other four checked it.  At 0 (the majorant
    alone) the few deposits under a tent made spikes in M (colored_sphere 0.09-0.31);
    docs/performance.md.
    ``lobe_window``: in a medium whose phase function is not flat, the camera's M from the
    traced paths is their moments' HG lobe fitted to their deposits over windows of
    (2 lobe_window + 1)^3 lattice points, as far as the deposits' noise warrants
    (precompute/lobefit.py); 0: the deposits alone.  Chosen from 1, 2 and 3 on the public
    suite (docs/method.md §9.9).
    ``surface_cache``: the surfaces' gathered light is gathered once at points of a grid over
    the image this many points across its width, and each camera sample on a surface
    interpolates it (surfacecache.py); below 2: every sample gathers itself
    (``surface_gathers``).  ``surface_cache_gathers``: the directions each grid point gathers
    through; ``surface_cache_smooth``: passes of the 3 x 3 filter over the grid
    (surfacecache.SurfaceCache.smooth).
    ``surface_bounces``: surface-to-surface bounces a surface's gathers follow
    (surfaces.shade's ``bounces``): where a gather meets another surface, that point's own
    light is reflected: its lights, the volumes' light along its own one gather, and with 2
    the surfaces that gather meets (Cycles' diffuse bounces, which count no volume bounce,
    so they are in its single-scattering references: 4 in the suite's files).  Pillars
    standing on a spot-lit ground in fog (p_fog_spot_shafts), lit only by the ground,
    single scattering at 16 spp (rel_rmse_4, bias): 0.0317 (-0.0118) with one bounce that
    left out the fog's glow on the ground; with it 0.0262 (-0.0077) at 1, 0.0239 (-0.0041)
    at 2, 0.0240 (-0.0037) at 3; p_fog_point 0.0088 (-0.0017), 0.0058, 0.0054 (-0.0001),
    0.0055; the suite's other 26 scenes the same bits (a lone ground sees no other
    surface).  Its cost at 1920x1080, F12: the second bounce without the glow nothing
    measurable (p_fog_spot_shafts 67.1 -> 67.6 s), the glow at 2 bounces p_fog_point 43.0 ->
    44.7 s, p_fog_spot_shafts 67.6 -> 71.8 s (docs/method.md §8).
    ``path_nodal``: each point of the traced paths' lattice holds the light at the point, not
    at its tent's density-weighted centroid, which lies inside the medium by up to a third of
    a step where the medium ends or changes under the tent (precompute/nodal.py: moved along
    the gradient fitted to its neighbours).  Off: the tent's mean, whose surfaces read the
    brighter light deeper in (p_sphere_thick's limb 5-36 % bright).  On the 28 scenes,
    full render: median 0.0222 -> 0.0215, worst 0.196 -> 0.178, p_sphere_thick
    0.074 -> 0.032, p_backlit_slab 0.029 -> 0.034 (docs/method.md §9.9, *Nodal values*).
    ``cell_tau``: in a density grid (a VDB, a shader's density; not a mesh volume, whose
    surface cells ``refined_tau`` marches), a march sample whose cell's most extinguishing
    voxel is at least this optical depth across (its extinction times the voxel size)
    follows each light's path cell by cell, Simpson's rule over each piece, for at most
    ``cell_walk`` cells while they stay that thick, and reads the light's depth where the
    path ends, on a plane of voxel centres (kernels_np._walk_tau), not trilinearly between
    the centres: in such a cell the depth bends with the density, and where light enters a
    voxel of depth d from an empty one the trilinear read darkens the cell's single
    scattering by about d/12 (2 % at 0.25; 20 % at d = 2.5; docs/method.md, "Light in an
    optically thick voxel").  The same cells' lit voxels march their depth
    (lightdepth.near_thick_cells) and take the paths' source from points of their cells
    (source.thick_band_source).  At 0.05 most of a cloud's voxels qualified (cloud_vdb 130 000
    of 180 000) and its precompute took about 1.5 s more; at 0.25, 9 800; a third-party
    dragon at 1.2-2.5 a voxel has three quarters of its voxels above it either way; 0: off.
    ``cell_walk``: those cells at most (0: the next plane of centres along the light's main
    axis alone).  The dragon at 2.5 a voxel, sun alone, single scattering over Cycles':
    0.919 on the next plane alone, 0.940 / 0.945 following up to 4 / 8 cells (docs/method.md
    §5; 8 cost p_dragon's render at 1920x1080 6.7 s against 4's 5.7 s for 0.0195 against
    0.0203), 0.975 with every sample's depth marched to the light.
    ``ambient_resolution``: the sky's light A (precompute/worldlight.py) is computed on a
    lattice about this many points along a grid's longest side and interpolated to the
    voxels.  ``ambient_refine``: the voxels of a lattice cell between whose corners A
    falls so steeply that interpolating it linearly would miss, at the cell's middle, more than this fraction of the world's
    radiance if it fell exponentially (worldlight.interpolation_error) get A at their own
    centres (0: off; smaller: more voxels, converging on A at every voxel).  In a medium
    optically thick across a lattice cell the sky's lit layer is thinner than the cell and
    the interpolation, a chord under a convex fall, was too bright: p_sphere_g95's single
    scattering 0.0139 (bias +0.0043) at 0, 0.0041 at 0.1, 0.0027 at 0.03, with about 56 000
    and 217 000 of its 1.2 M voxels computed (docs/method.md §7).
    ``sky_deficit_paths``: the paths of the fictitious emission sigma_a L_w whose later flights
    are the sky's light an absorbing medium loses (precompute/skydeficit.py), as a share of
    the Paths setting (or of emissionlight.EMISSION_PATHS where that is more: the Preview's
    walk has no paths; its render of p_sphere_lowalbedo at 480x270 took 1.1 s more with all
    250 000).  The sky's multiple scattering alone over Cycles' (benchmarks/sky_split.py,
    160x120) at all the 3 000 000 paths, 1/8 and 1/32: p_sphere_gneg 0.976 / 0.979 / 0.976,
    p_sphere_thick 0.977 / 0.973 / 0.970, p_sphere_lowalbedo 0.964 / 0.936 at the first two
    (the thick sphere's render with the sky alone 45 / 7.7 s at the first two; measured
    before the lattice's points were left signed, after which 1/8 gives 0.972, 0.978 and
    0.961: docs/method.md §9.8).  A share times the medium's absorbed fraction (1 - albedo;
    1/4 of the paths at albedo 0) saved cloud_vdb's 0.7 s at 1920x1080 but took its full
    render 0.0161 -> 0.0215, p_sphere_g95 0.0827 -> 0.0916 and slab_forward 0.0403 ->
    0.0458: the deficit of a thick white medium is not small deep inside, and its few
    paths' noise showed.
    ``sky_deficit_mix``: the share of those paths drawn by the emission's power alone; the
    rest also by how well the camera sees the light the path will carry
    (skydeficit.camera_odds), so that no path weighs more than 1 / mix of its plain weight.
    p_sphere_lowalbedo's seed-to-seed noise of the whole image (4 x 4 blocks) was 0.0083
    with every path by its power, 0.0058 / 0.0058 / 0.0064 at 0.1 / 0.2 / 0.35 (with the
    odds softened as exp(-tau_c / 4), the first form tried), 0.0061 as now; at 0.2 with a
    reach of 3: p_sphere_gneg 0.0054 -> 0.0058, cloud_vdb 0.0154 -> 0.0152,
    slab_isotropic 0.0108 -> 0.0108 (within two seeds' scatter; docs/method.md §9.8).
    ``camera_roulette``: the floor of the odds by which the lights' paths play the camera's
    roulette where the camera cannot see their light (precompute/camerareach.py, paths.py
    "The camera's roulette"): past the walk's reach a path goes on with odds falling by e
    every diffusion length, down to this, and weighs as much more, at most
    1 / camera_roulette of its plain weight; 1 switches it off.  Unbiased at any value: it
    trades the paths' work for their noise.  0.1 as a test build measured it on
    p_sphere_thick (one roulette a path at an optical depth of 20 from the camera:
    precompute 51 / 56 -> 32 / 36 s, full render 0.0246 / 0.0261 -> 0.0246 / 0.0257 at
    seeds 0 / 1; at 0.25 37 / 40 s, 0.0243 / 0.0265); as now 70 / 62 -> 53 / 57 s, 0.0246 /
    0.0261 -> 0.0247 / 0.0261 (docs/performance.md, 2026-12-07).
    ``core_refine``: round a light inside a medium the traced paths' lattice keeps to half
    the core of its first scatterings (precompute.lattice.lamp_resolution), at most this
    many times finer along the longest side than the Multiple Scattering Resolution: on a
    large grid the voxels themselves cost what the field does and more (a 200-voxel cloud
    with a pure point light inside, on its voxels: 294 s and 3.7 GB peak, against 53 s and
    1.1 GB at Resolution 64; docs/performance.md, 2026-12-08); no scene of the suite or the
    hold-outs asks for more than 2x."""

    skip_min_voxels: int = 1 << 20
    spot_cull: bool = True
    refine: int = 2
    first_flights: bool = True
    exact_flights: int = 2
    flatten: bool = True
    skip_empty: bool = True
    adapt_tau: float = 0.1
    tile: int = 128
    tile_rays: int = 4096
    tile_rays_most: int = 16384
    tile_samples: float = 400_000.0
    surface_gathers: int = 4
    adaptive_first: int = 4
    pilot_stride: int = 8
    step_voxels: float = 0.5
    pilot_samples: int = 4
    gather_moments: bool = True
    roulette: float = 0.01
    gather_step: float = 4.0
    disc_exact: float = 2.0
    disc_voxels: float = 16.0
    disc_fold_stride: int = 4
    disc_fold_nodes: int = 16
    guided_gathers: float = 0.5
    smooth_step_voxels: float = 1.0
    smooth_step_tau: float = 0.5
    path_deposits: float = 0.5
    lobe_window: int = 3
    path_nodal: bool = True
    cell_tau: float = 0.25
    cell_walk: int = 4
    ambient_resolution: int = 32
    ambient_refine: float = 0.1
    surface_cache: int = 240
    surface_cache_gathers: int = 128
    surface_cache_smooth: int = 1
    surface_bounces: int = 2
    sky_deficit_paths: float = 0.125
    sky_deficit_mix: float = 0.2
    camera_roulette: float = 0.1
    core_refine: int = 2


# The default Noise Threshold (pilot.py's unit: the standard error over sqrt(I S), S the
# frame's mean luminance).  Cycles' default, 0.01 over sqrt(I) with I display-referred, is
# this at a frame of mean luminance S = 0.25 (0.01 / sqrt(0.25) = 0.02): Cycles' noise where
# a frame is exposed as artists expose it.  Per pixel it keeps a relative noise of 2 % of S,
# 0.5 % in the metric's 4 x 4 blocks (docs/adaptive.md).
NOISE_THRESHOLD = 0.02

# light paths per light and medium at the default quality (docs/method.md, "Traced paths")
MULTIPLE_PATHS = 3_000_000

# What the Quality menu sets (blender/properties.py; docs/usage.md gives what each costs and
# how close it comes on the public scenes).  Preview: the walk's smooth, biased multiple
# scattering and few samples; Final (the defaults): traced paths, adaptive sampling;
# Reference: every sample in every pixel, four times the paths on a lattice twice as fine,
# the surfaces' light gathered by every sample (no surface cache), for a converged look at
# 8x the memory per lattice.
QUALITY_PRESETS = {
    "PREVIEW": dict(samples=4, noise_threshold=NOISE_THRESHOLD, multiple_paths=0,
                    multiple_resolution=64, surface_cache=True),
    "FINAL": dict(samples=16, noise_threshold=NOISE_THRESHOLD, multiple_paths=MULTIPLE_PATHS,
                  multiple_resolution=64, surface_cache=True),
    "REFERENCE": dict(samples=16, noise_threshold=0.0, multiple_paths=4 * MULTIPLE_PATHS,
                      multiple_resolution=128, surface_cache=False),
}


@dataclass
class Settings:
    """Render quality settings.

    ``samples``: jittered rays per pixel (box filter over the pixel square), at most.
    ``noise_threshold``: adaptive sampling (tiles.FrameMarch.tile, pilot.py): a pixel stops
    taking samples once the standard error of its mean luminance is below this many times
    sqrt(I S), I its mean and S the frame's (W/(m^2 sr)): the relative noise the frame keeps,
    the same at any exposure; 0: every pixel takes ``samples``.
    ``step_size``: march step in metres; 0 picks ``Tuning.step_voxels`` (half) of the finest
    voxel's side.
    ``multiple``: compute multiple scattering (MPP).  ``film_transparent``: alpha from
    transmittance instead of 1.  ``seed``: jitter seed (same seed, same image).
    ``ambient_directions``: directions used to integrate the world light's transmittance.
    ``multiple_resolution``: lattice points along a medium's longest side for the light
    pyramids of multiple scattering (precompute.lightpyramid; never finer than the voxels).
    ``multiple_paths``: light paths traced per light and medium for multiple scattering
    (paths.py, precompute.lightpaths; more: less noise in it); 0: the walk of the light
    pyramid instead (walk.py).
    ``passes``: names of the passes to fill; None means every pass the engine has.
    ``voxel_resolution``: voxels along the longest side when a mesh volume is voxelised.
    ``threads``: worker threads for the march; 0 means one per core.
    ``surface_bounce``: surfaces reflect light into the media (indirect light, so only with
    ``multiple``): the traced paths start on the lit surfaces and reflect off every surface
    (precompute.pathstarts); with the walk (``multiple_paths`` 0) flat surfaces become area
    lights (bounce.py; not under a world volume).
    ``surface_cache``: the light a surface gathers from the sky, the volumes and the other
    surfaces is gathered once on a grid over the image and interpolated (surfacecache.py,
    ``Tuning.surface_cache``); False: every camera sample gathers it (unbiased per sample,
    noisier, dearer where a ground is in view).
    ``memory_budget_mb``: megabytes (2^20 bytes) the precompute fields may take; larger grids
    are box-downsampled with a warning (budget.py); 0 means unlimited.
    ``tuning``: the method's speed and exactness knobs (Tuning; not in the user interface).
    """

    samples: int = 16
    noise_threshold: float = NOISE_THRESHOLD
    step_size: float = 0.0
    multiple: bool = True
    film_transparent: bool = False
    seed: int = 0
    ambient_directions: int = 32
    multiple_resolution: int = 64
    multiple_paths: int = MULTIPLE_PATHS
    passes: Optional[List[str]] = None
    threads: int = 0
    voxel_resolution: int = 128
    memory_budget_mb: int = 2048
    surface_bounce: bool = True
    surface_cache: bool = True
    tuning: Tuning = field(default_factory=Tuning)


@dataclass
class SceneDescription:
    """Everything one frame of one view layer needs, free of Blender objects."""

    camera: Camera
    lights: List[Light] = field(default_factory=list)
    media: List[Medium] = field(default_factory=list)
    surfaces: List[Surface] = field(default_factory=list)
    world: World = field(default_factory=World)
    settings: Settings = field(default_factory=Settings)
    warnings: List[str] = field(default_factory=list)
