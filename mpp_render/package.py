"""The installable extension zip: ``python -m mpp_render package --output-dir DIR``.

The compiled kernels travel as a wheel, the way Blender extensions ship binary modules::

    repository --copy--> staging dir (no .git/.venv/build outputs, no loose *.so)
      setup.py build_ext (mpp_render/csrc/*.c, the project's own flags; sanitizers off)
        --> _kernels*.so
      --> wheels/mpp_render_kernels-<version>-cp311-cp311-linux_x86_64.whl
          (top-level package ``mpp_render_kernels`` holding that ``_kernels`` module)
      staged blender_manifest.toml gets ``wheels = ["./wheels/...whl"]``
      --> Blender's builder (bl_pkg/cli/blender_ext.py build, then validate) --> DIR/<id>-<version>.zip

On enable Blender extracts the wheel into its extensions' shared ``site-packages`` and puts
that on ``sys.path``; ``mpp_render.kernels`` then imports ``mpp_render_kernels._kernels`` when
the in-place ``mpp_render._kernels`` is absent.  On a platform the wheel does not fit Blender
skips it and the engine renders on the numpy kernels.

The wheel is assembled here (zip + ``.dist-info`` with a RECORD of sha256 hashes) from the
module that ``setup.py build_ext`` compiles, so the kernels are built exactly as in a
checkout; no ``bdist_wheel`` is needed.  Nothing in the repository is written: every build
product lives in a temporary directory.  This module imports neither bpy nor numpy.
"""
from __future__ import annotations

import base64
import glob
import hashlib
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
import tomllib
import zipfile
from importlib.util import find_spec
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
KERNELS_DIST = "mpp_render_kernels"      # the wheel's distribution name
KERNELS_PACKAGE = "mpp_render_kernels"   # its top-level package; the C module is ``._kernels``
KERNELS_MODULE = "_kernels"
MANIFEST = "blender_manifest.toml"
WHEELS_DIR = "wheels"

# Not copied to the staging directory: version control, environments, build outputs, caches
# and compiled modules (the kernels go in the wheel only).  The manifest's own
# ``paths_exclude_pattern`` still decides what of the rest goes into the zip.
SKIP_TOP = {".git", ".venv", "build", "dist", "out", WHEELS_DIR, ".pytest_cache"}
SKIP_ANY = ("__pycache__", "*.pyc", "*.so", "*.pyd", "*.egg-info")

# ZIP entries get this fixed time, so the same module gives the same wheel.
ZIP_DATE = (1980, 1, 1, 0, 0, 0)

_INIT_PY = '''"""mpp_render's compiled kernels, shipped as a wheel inside the MPP Render extension.

``mpp_render.kernels`` imports ``mpp_render_kernels._kernels`` when its in-place twin
(``mpp_render._kernels``) is absent.
"""
from . import _kernels  # noqa: F401
'''


class PackageError(RuntimeError):
    """A packaging step failed; the message holds the failing tool's output."""


def blender_ext_cli() -> Path:
    """Blender's extension command line (``bl_pkg/cli/blender_ext.py``) in the bpy module."""
    spec = find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise PackageError("the bpy module is not installed: no extension builder")
    for root in spec.submodule_search_locations:
        found = sorted(glob.glob(os.path.join(root, "*", "scripts", "addons_core", "bl_pkg",
                                              "cli", "blender_ext.py")))
        if found:
            return Path(found[-1])
    raise PackageError("blender_ext.py not found in the bpy module")


def wheel_tag() -> str:
    """``python-abi-platform`` of this interpreter, e.g. ``cp311-cp311-linux_x86_64``."""
    py = f"cp{sys.version_info[0]}{sys.version_info[1]}"
    platform = re.sub(r"[^A-Za-z0-9_]", "_", sysconfig.get_platform())
    return f"{py}-{py}-{platform}"


def read_manifest(source_dir: Path) -> dict:
    with open(source_dir / MANIFEST, "rb") as fh:
        return tomllib.load(fh)


def stage_source(source_dir: Path, stage: Path, output_dir: Path | None = None) -> None:
    """Copy the extension's source tree to ``stage`` (which must not exist)."""
    source_dir = source_dir.resolve()
    skip_paths = set()
    if output_dir is not None:
        skip_paths.add(output_dir.resolve())
    any_pattern = shutil.ignore_patterns(*SKIP_ANY)

    def ignore(directory, names):
        d = Path(directory).resolve()
        skipped = set(any_pattern(directory, names))
        if d == source_dir:
            skipped |= SKIP_TOP & set(names)
        skipped |= {n for n in names if (d / n) in skip_paths}
        return skipped

    shutil.copytree(source_dir, stage, ignore=ignore)


def build_kernels(stage: Path, work: Path) -> Path:
    """Compile ``mpp_render._kernels`` with the staged ``setup.py`` into ``work``; returns the
    module file.  ``MPP_SANITIZE`` is dropped: a shipped module must not need the sanitizer
    runtimes."""
    env = {k: v for k, v in os.environ.items() if k != "MPP_SANITIZE"}
    cmd = [sys.executable, "setup.py", "-q", "build_ext", "--build-lib", str(work / "lib"),
           "--build-temp", str(work / "tmp")]
    p = subprocess.run(cmd, cwd=stage, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise PackageError(f"building the C kernels failed:\n{p.stdout}\n{p.stderr}")
    suffix = sysconfig.get_config_var("EXT_SUFFIX")
    module = work / "lib" / "mpp_render" / f"{KERNELS_MODULE}{suffix}"
    if not module.is_file():
        raise PackageError(f"setup.py build_ext made no {module.name}")
    return module


def _record_hash(data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=")
    return "sha256=" + digest.decode("ascii")


def write_wheel(module: Path, out_dir: Path, version: str, tag: str | None = None) -> Path:
    """Assemble the kernels wheel from the compiled ``module`` into ``out_dir``: the package
    ``mpp_render_kernels`` (``__init__.py`` + the module under its own file name, so its
    ``PyInit__kernels`` is found) and a ``.dist-info`` (METADATA, WHEEL, top_level.txt,
    RECORD).  Returns the wheel's path."""
    tag = tag or wheel_tag()
    dist_info = f"{KERNELS_DIST}-{version}.dist-info"
    files = [
        (f"{KERNELS_PACKAGE}/__init__.py", _INIT_PY.encode()),
        (f"{KERNELS_PACKAGE}/{module.name}", module.read_bytes()),
        (f"{dist_info}/METADATA", (
            "Metadata-Version: 2.1\n"
            f"Name: {KERNELS_DIST}\n"
            f"Version: {version}\n"
            "Summary: Compiled ray-marching kernels of the MPP Render Blender extension\n"
            "License: GPL-3.0-or-later\n"
            "Requires-Python: >=3.11\n").encode()),
        (f"{dist_info}/WHEEL", (
            "Wheel-Version: 1.0\n"
            "Generator: mpp_render.package\n"
            "Root-Is-Purelib: false\n"
            f"Tag: {tag}\n").encode()),
        (f"{dist_info}/top_level.txt", f"{KERNELS_PACKAGE}\n".encode()),
    ]
    record = "".join(f"{name},{_record_hash(data)},{len(data)}\n" for name, data in files)
    record += f"{dist_info}/RECORD,,\n"
    files.append((f"{dist_info}/RECORD", record.encode()))

    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{KERNELS_DIST}-{version}-{tag}.whl"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in files:
            info = zipfile.ZipInfo(name, ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = (0o755 if name.endswith(module.name) else 0o644) << 16
            zf.writestr(info, data)
    return path


def add_wheel_to_manifest(manifest_path: Path, wheel_rel: str) -> list:
    """Add ``wheel_rel`` (``./wheels/...``) to the ``wheels`` list of a manifest file, as a
    top-level key (before the first table) or appended to an existing list.  Returns the
    new list."""
    text = manifest_path.read_text()
    wheels = list(tomllib.loads(text).get("wheels", []))
    if wheel_rel not in wheels:
        wheels.append(wheel_rel)
    line = "wheels = [" + ", ".join(f'"{w}"' for w in wheels) + "]"
    if re.search(r"(?m)^wheels\s*=", text):
        text = re.sub(r"(?ms)^wheels\s*=\s*\[.*?\]", line, text, count=1)
    else:
        m = re.search(r"(?m)^\s*\[", text)
        at = m.start() if m else len(text)
        text = text[:at] + "# Added by mpp_render.package: the compiled kernels.\n" + line + "\n\n" + text[at:]
    if tomllib.loads(text).get("wheels") != wheels:
        raise PackageError(f"could not add {wheel_rel} to {manifest_path}")
    manifest_path.write_text(text)
    return wheels


def _run_ext_cli(*args: str) -> str:
    p = subprocess.run([sys.executable, str(blender_ext_cli()), *args], capture_output=True,
                       text=True)
    if p.returncode != 0:
        raise PackageError(f"blender_ext.py {args[0]} failed:\n{p.stdout}\n{p.stderr}")
    return p.stdout


def package(output_dir, source_dir=REPO) -> dict:
    """Build ``<output_dir>/<id>-<version>.zip`` from ``source_dir`` with the kernels wheel
    (an existing zip of that name is replaced).  Returns ``{"zip", "wheel", "kernels",
    "seconds"}``: the zip's path, the wheel's path inside it, the module it carries."""
    t0 = time.perf_counter()
    source_dir = Path(source_dir).resolve()
    output_dir = Path(output_dir).resolve()
    output_dir.mkdir(parents=True, exist_ok=True)  # the builder wants it to exist
    manifest = read_manifest(source_dir)
    ext_id, version = manifest["id"], manifest["version"]

    tmp = Path(tempfile.mkdtemp(prefix="mpp_package_"))
    try:
        stage = tmp / ext_id
        stage_source(source_dir, stage, output_dir)
        module = build_kernels(stage, tmp / "kernels")
        wheel = write_wheel(module, stage / WHEELS_DIR, version)
        wheel_rel = f"{WHEELS_DIR}/{wheel.name}"
        add_wheel_to_manifest(stage / MANIFEST, "./" + wheel_rel)

        zip_path = output_dir / f"{ext_id}-{version}.zip"
        if zip_path.exists():
            zip_path.unlink()
        _run_ext_cli("build", "--source-dir", str(stage), "--output-dir", str(output_dir))
        if not zip_path.is_file():
            raise PackageError(f"the builder made no {zip_path}")
        _run_ext_cli("validate", str(zip_path))
        return {"zip": str(zip_path), "wheel": wheel_rel,
                "kernels": f"{KERNELS_PACKAGE}.{KERNELS_MODULE}",
                "seconds": round(time.perf_counter() - t0, 3)}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def cmd_package(args) -> dict:
    """The ``package`` sub-command: builds the zip, returns the record main() prints."""
    return package(args.output_dir, source_dir=args.source_dir or REPO)
