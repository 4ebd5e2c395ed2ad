"""What the renderer keeps between renders, so frames of an animation and re-renders of an
unchanged scene reuse the work that did not change (no bpy).

One store, ``CACHE``, holds entries of a few kinds under content keys (``digest``), with a
memory cap (``MPP_CACHE_MB``, default ``DEFAULT_LIMIT_MB``; least recently used entries go
first) and hit/miss counters:

* ``'precompute'``: the precompute fields and light pyramids, under a key of what the light
  part reads -- the prepared media (grids, maps, coefficients), the lights, the opaque
  surfaces' geometry, multiple scattering on/off and, with it on, the camera position that
  ``precompute.drift_levels`` reads -- with the key of the world-light part
  they hold: the world colour, the ambient directions, the seed and the camera *position*
  (the direction for an orthographic camera), which ``precompute.worldlight.world_light`` reads.
  Turning a perspective camera keeps everything; moving it recomputes the world light only
  (and the light pyramids, with multiple scattering on); changing a light keeps the world
  light (``precompute_cached``).
* the Blender glue stores grids it read or built: ``'voxels'`` (voxelised mesh interiors),
  ``'vdb'`` (grids of unchanged .vdb files), ``'fluid'`` (fluid cache frames).

``clear()`` empties the store (the *Clear MPP Caches* operator calls it).  Values are
returned as stored: callers must not modify the arrays they get.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import threading
from collections import OrderedDict
from typing import Callable, Dict, Optional

import numpy as np

MB = 1 << 20
DEFAULT_LIMIT_MB = 1024
ENTRY_BYTES = 256  # counted for every entry besides its arrays (keys, small objects)
LIMIT_ENV = "MPP_CACHE_MB"


def nbytes(obj) -> int:
    """Bytes held by the numpy arrays in ``obj`` (dicts, lists, tuples, dataclass fields)."""
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if isinstance(obj, dict):
        return sum(nbytes(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(nbytes(v) for v in obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return sum(nbytes(getattr(obj, f.name)) for f in dataclasses.fields(obj))
    return 0


def _feed(h, obj) -> None:
    """Add ``obj`` to the hash ``h`` unambiguously: type tags, shapes and lengths go in with
    the values, so (1, 2) and [1, 2] or a (2, 3) and a (3, 2) array differ."""
    if obj is None:
        h.update(b"N")
    elif isinstance(obj, (bool, np.bool_)):
        h.update(b"B1" if obj else b"B0")
    elif isinstance(obj, (int, np.integer)):
        h.update(b"I" + str(int(obj)).encode())
    elif isinstance(obj, (float, np.floating)):
        h.update(b"F" + np.float64(obj).tobytes())
    elif isinstance(obj, str):
        b = obj.encode("utf-8", "surrogatepass")
        h.update(b"S" + str(len(b)).encode() + b":" + b)
    elif isinstance(obj, bytes):
        h.update(b"Y" + str(len(obj)).encode() + b":" + obj)
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(b"A" + a.dtype.str.encode() + repr(a.shape).encode())
        h.update(memoryview(a).cast("B"))
    elif isinstance(obj, (list, tuple)):
        h.update(b"L" + str(len(obj)).encode())
        for v in obj:
            _feed(h, v)
    elif isinstance(obj, dict):
        h.update(b"D" + str(len(obj)).encode())
        for k in sorted(obj, key=repr):
            _feed(h, k)
            _feed(h, obj[k])
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(b"C" + type(obj).__name__.encode())
        for f in dataclasses.fields(obj):
            _feed(h, f.name)
            _feed(h, getattr(obj, f.name))
    else:
        raise TypeError(f"cannot hash a {type(obj).__name__} into a cache key")


def digest(*parts) -> str:
    """A content hash (hex) of numpy arrays, numbers, strings, sequences, dicts and
    dataclasses: equal content gives an equal key, any change a different one."""
    h = hashlib.blake2b(digest_size=20)
    _feed(h, parts)
    return h.hexdigest()


def limit_bytes() -> int:
    """The cap from ``MPP_CACHE_MB`` (megabytes, 0 disables the cache), else the default."""
    text = os.environ.get(LIMIT_ENV, "")
    try:
        mb = float(text) if text.strip() else float(DEFAULT_LIMIT_MB)
    except ValueError:
        mb = float(DEFAULT_LIMIT_MB)
    return max(0, int(mb * MB))


class Cache:
    """A least-recently-used store of values by ``(kind, key)`` with a cap on the bytes of
    their numpy arrays (``limit``, or ``limit_bytes()`` read at every insertion when None).
    A value larger than the cap is not stored.  Thread-safe."""

    def __init__(self, limit: Optional[int] = None):
        self.limit = limit
        self._items: "OrderedDict[tuple, tuple]" = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits: Dict[str, int] = {}
        self.misses: Dict[str, int] = {}

    def _cap(self) -> int:
        return limit_bytes() if self.limit is None else int(self.limit)

    def get(self, kind: str, key):
        """The value stored under ``(kind, key)`` or None; counts a hit or a miss."""
        with self._lock:
            item = self._items.get((kind, key))
            if item is None:
                self.misses[kind] = self.misses.get(kind, 0) + 1
                return None
            self._items.move_to_end((kind, key))
            self.hits[kind] = self.hits.get(kind, 0) + 1
            return item[0]

    def put(self, kind: str, key, value) -> bool:
        """Store ``value``; the oldest entries are dropped until the cap holds.  False when
        the value alone exceeds the cap (then it is not stored).  Each entry counts its
        arrays' bytes plus ``ENTRY_BYTES``, so a zero cap keeps nothing at all."""
        size = nbytes(value) + ENTRY_BYTES
        cap = self._cap()
        with self._lock:
            old = self._items.pop((kind, key), None)
            if old is not None:
                self._bytes -= old[1]
            if size > cap:
                return False
            self._items[(kind, key)] = (value, size)
            self._bytes += size
            while self._bytes > cap and self._items:
                _, (_, dropped) = self._items.popitem(last=False)
                self._bytes -= dropped
            return True

    def clear(self) -> int:
        """Drop every entry and reset the counters; returns the bytes released."""
        with self._lock:
            freed = self._bytes
            self._items.clear()
            self._bytes = 0
            self.hits.clear()
            self.misses.clear()
            return freed

    @property
    def bytes(self) -> int:
        return self._bytes

    def __len__(self) -> int:
        return len(self._items)

    def stats(self) -> dict:
        """``{"entries", "mb", "limit_mb", "hits": {kind: n}, "misses": {kind: n}}``."""
        with self._lock:
            return {"entries": len(self._items), "mb": self._bytes / MB,
                    "limit_mb": self._cap() / MB, "hits": dict(self.hits),
                    "misses": dict(self.misses)}

    def store(self, kind: str) -> "KindView":
        """A dict-like view on one kind (``get(key)``, ``view[key] = value``)."""
        return KindView(self, kind)


class KindView:
    """``get``/``__setitem__`` on one kind of a :class:`Cache`, for code written against a
    plain dict.  The view also keeps what passes through it itself, so within its lifetime
    (one scene translation) a value is shared even when the cache is full or switched off."""

    def __init__(self, cache: Cache, kind: str):
        self.cache, self.kind = cache, kind
        self.local: dict = {}

    def get(self, key, default=None):
        if key in self.local:
            return self.local[key]
        value = self.cache.get(self.kind, key)
        if value is None:
            return default
        self.local[key] = value
        return value

    def __setitem__(self, key, value) -> None:
        self.local[key] = value
        self.cache.put(self.kind, key, value)


CACHE = Cache()


def clear() -> int:
    """Empty ``CACHE``; returns the bytes released."""
    return CACHE.clear()


# -- the precompute ---------------------------------------------------------------------------

def media_key(media) -> str:
    """Content key of prepared media (precompute reads their grids, maps, coefficients,
    anisotropy, sharpness and emission: the emission grid's channels and the glow's light; the
    scatter colour grid's channels; the extinction density's)."""
    return digest([(pm.grid, pm.w2i, pm.sigma_s, pm.sigma_a, float(pm.g), float(pm.threshold),
                    np.asarray(pm.medium.emission, np.float64), pm.emission_grid,
                    pm.scatter_grid, pm.extinction_density)
                   for pm in media])


def surfaces_key(surfaces) -> str:
    """Content key of a SurfaceSet's geometry and shading (the precompute's occluders, what
    the traced paths reflect off, and the share of the sky each reflects, which every layer
    of its BSDF sets: precompute/skydeficit.py), or of None."""
    if surfaces is None or surfaces.empty:
        return digest(None)
    return digest(surfaces.v0, surfaces.e1, surfaces.e2, surfaces.surface,
                  *[np.asarray(surfaces.params[k]) for k in sorted(surfaces.params)])


def camera_key(camera) -> tuple:
    """What ``precompute.worldlight.world_light`` reads of the camera: the position of a perspective
    camera, the view axis of an orthographic one."""
    c2w = np.asarray(camera.cam_to_world, np.float64)
    if camera.projection == "ORTHO":
        return ("ORTHO", c2w[:3, 2].copy())
    return (str(camera.projection), c2w[:3, 3].copy())


def precompute_cached(media, lights, world, camera, *, n_dirs: int, seed: int, surfaces=None,
                      threads: int = 0, multiple: bool = False, multiple_resolution=None,
                      multiple_paths: int = 0, should_cancel: Optional[Callable[[], bool]] = None,
                      progress=None, cache: Optional[Cache] = None, tuning=None,
                      surface_bounce: bool = True, any_camera: bool = False):
    """``precompute.precompute`` reusing earlier results kept in ``cache`` (default ``CACHE``).

    One entry (kind 'precompute') per *light key* -- the media, lights, surfaces, multiple
    scattering, its resolution and traced paths (and then the camera position, and the seed
    of the paths), thread count, the tuning
    (scene.Tuning) and whether the world is lit -- holds the fields and pyramids
    and the *world key* they were computed for (world colour, camera position, ambient
    directions, seed).  Then:

    * both keys match: everything is reused;
    * only the world key differs (the camera moved): the world part alone is computed
      (``precompute`` without lights) and written over the entry's world channels;
    * the light key is new but an entry holds the same world key and the same channel
      layout (a light's power or colour changed): the light part alone is computed and the
      world channels are copied from that entry;
    * otherwise the whole precompute runs.

    The result equals a cold ``precompute`` call's: in it the light channels, the pyramids and
    the world channels are computed independently.  ``stats["reused"]`` lists the parts
    taken from the cache ('lights', 'world').

    ``any_camera``: when nothing is kept for this camera, the entry last kept for the same
    scene seen from another camera position (the same light key but for the camera) is
    returned as it is, with ``stats["stale_camera"]`` True: its world light and its pyramids'
    phase towards the camera are the other position's; and when a light changed, the world
    channels may come from an entry of another camera position (then the new entry is kept
    under that position's world key, so an exact lookup never takes them).  The viewport's
    first, coarse picture while the view orbits uses it (viewport.py); nothing else does.
    A cancelled precompute changes nothing (it raises cancel.Cancelled).  Callers must not
    modify the returned arrays."""
    from . import precompute as pre_mod
    from .precompute.lattice import MULTIPLE_RESOLUTION
    from .precompute.layout import light_channels
    from .precompute.skydeficit import walls_follow_lights
    from .scene import Tuning, World
    from .media import glow_lights

    cache = CACHE if cache is None else cache
    tuning = Tuning() if tuning is None else tuning
    if multiple_resolution is None:
        multiple_resolution = MULTIPLE_RESOLUTION
    # the media's glow scattered in them (precompute.emissionlight) sits in the world
    # channels and, like the world light, is read towards the camera
    has_world = bool(np.any(np.asarray(world.color, np.float64) > 0)) or glow_lights(media)
    # the thread count does not change the numbers; it is keyed anyway so that a render with
    # other threads still runs (and checks) the precompute
    common = (media_key(media), surfaces_key(surfaces), bool(multiple),
              int(multiple_resolution) if multiple else 0,
              int(multiple_paths) if multiple else 0, int(threads), tuning,
              bool(surface_bounce) if multiple else None)
    # the light pyramids are moved towards what the camera sees (precompute.lightpyramid.drift_levels)
    seeded = int(seed) if multiple and multiple_paths > 0 else None
    # the surfaces' share of the sky's deficit takes as many paths as weigh what the lights'
    # weigh (precompute/skydeficit.py): the two parts are made together then
    walls = walls_follow_lights(multiple, multiple_paths, surfaces, world.color, media)
    light_key = digest("lights", common, list(lights), has_world,
                       camera_key(camera) if multiple else None, seeded,
                       np.asarray(world.color, np.float64) if walls else None)
    scene_key = digest("scene", common, list(lights), has_world, seeded)
    world_key = digest("world", common, np.asarray(world.color, np.float64), camera_key(camera),
                       int(n_dirs), int(seed)) if has_world else None
    world_any_key = digest("world", common, np.asarray(world.color, np.float64),
                           int(n_dirs), int(seed)) if has_world else None
    kw = dict(n_dirs=n_dirs, seed=seed, should_cancel=should_cancel, progress=progress,
              surfaces=surfaces, threads=threads, multiple=multiple,
              multiple_resolution=multiple_resolution, multiple_paths=multiple_paths,
              tuning=tuning, surface_bounce=surface_bounce)

    def result(pre, reused, stale=False):
        stats = dict(pre.stats, reused=reused)
        if stale:
            stats["stale_camera"] = True
        return pre_mod.Precomputed(pre.fields, pre.layout, pre.multiple, pre.seconds, stats,
                                   pre.glow_moments)

    entry = cache.get("precompute", light_key)
    if entry is not None:
        pre = entry["pre"]
        if entry["world"] == world_key:
            return result(pre, ["lights", "world"] if has_world else ["lights"])
        if any_camera:      # the world light of another camera position will do
            return result(pre, ["lights", "world"], stale=True)
        part = pre_mod.precompute(media, [], world, camera, **kw)  # the camera moved
        first = pre.layout.world_first
        for f, w in zip(pre.fields, part.fields):
            f[..., first:] = w[..., 1:]
        pre.glow_moments = part.glow_moments   # the glow's, with the world channels
        entry["world"] = world_key
        return result(pre, ["lights"])
    if any_camera:
        other = cache.get("scene_index", scene_key)
        entry = cache.get("precompute", other) if other is not None else None
        if entry is not None:
            return result(entry["pre"], ["lights", "world"], stale=True)

    donor = None
    if has_world:
        donor_key = cache.get("world_index", world_key)
        if donor_key is None and any_camera:   # the world light of another camera position
            donor_key = cache.get("world_index", world_any_key)
        donor = cache.get("precompute", donor_key) if donor_key is not None else None
    if donor is not None and (donor["world"] == world_key or any_camera) and \
            donor["pre"].layout.light_channels == light_channels(lights):
        # a light changed
        part = pre_mod.precompute(media, lights, World(), camera, glow=False, **kw)
        old = donor["pre"]
        first = old.layout.world_first
        fields = []
        for fl, fo in zip(part.fields, old.fields):
            f = np.empty(fo.shape, np.float32)
            f[..., :first] = fl[..., :first]   # its own grids' channels are the donor's too
            f[..., first:] = fo[..., first:]
            fields.append(f)
        pre = pre_mod.Precomputed(fields, old.layout, part.multiple, part.seconds,
                                  dict(part.stats,
                                       ambient_points=old.stats.get("ambient_points", 0)),
                                  old.glow_moments)
        _keep(cache, light_key, donor["world"], scene_key, pre, world_any_key)
        return result(pre, ["world"], stale=donor["world"] != world_key)
    pre = pre_mod.precompute(media, lights, world, camera, **kw)
    _keep(cache, light_key, world_key, scene_key, pre, world_any_key)
    return result(pre, [])


def _keep(cache: Cache, light_key, world_key, scene_key, pre, world_any_key) -> None:
    """Store ``pre`` under ``light_key`` with the world key its world channels hold, and
    index it by its scene (any camera) and by its world light (this camera, any camera)."""
    cache.put("precompute", light_key, {"pre": pre, "world": world_key})
    cache.put("scene_index", scene_key, light_key)
    if world_key is not None:
        cache.put("world_index", world_key, light_key)
        cache.put("world_index", world_any_key, light_key)
