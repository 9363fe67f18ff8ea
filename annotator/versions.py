"""The libraries that shape labels, listed once, and their installed versions.

A label depends on the versions of the libraries that compute it: PyBullet simulates the trial,
NumPy does the arithmetic, trimesh reads, cleans and samples the mesh, pymeshfix fills its holes,
manifold3d joins overlapping shells, fast-simplification decimates what CoACD cuts, CoACD (and
PyBullet's V-HACD) cut the convex parts, SciPy (Qhull) makes their hulls. Two places must agree on
this list, and both read it from here:

- the run's binding (:func:`annotator.store.manifest.bound_versions`): a resume with another
  version of any of them is refused in one line (exit 2), so one folder never mixes labels made
  with two;
- the decomposition cache's key (:func:`annotator.objects.cache.entry_key`): an entry made with
  another version is a miss, and the object is decomposed again, never simulated with a shape
  another version made.

The versions are looked up through :func:`library_versions` (read once per process); both users
call it through this module, so a test that replaces it replaces what both see.
"""

from __future__ import annotations

import functools
import os
import platform
from importlib import metadata

__all__ = ["LABEL_LIBRARIES", "NOT_INSTALLED", "library_versions", "machine_kind"]

# Distribution names (as pip knows them), sorted; the order is part of no key (keys sort them).
LABEL_LIBRARIES: tuple[str, ...] = (
    "coacd",
    "fast-simplification",
    "manifold3d",
    "numpy",
    "pybullet",
    "pymeshfix",
    "scipy",
    "trimesh",
)
NOT_INSTALLED = "not installed"


def library_versions() -> dict[str, str]:
    """``{distribution: version}`` of :data:`LABEL_LIBRARIES` (``"not installed"`` for a missing one)."""
    return dict(_installed())


@functools.cache
def _installed() -> dict[str, str]:
    out = {}
    for dist in LABEL_LIBRARIES:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = NOT_INSTALLED
    return out


# The kind of machine a label was computed on, besides the versions above. The same versions on
# two machines give the same labels bit for bit except where a computation takes a path that
# depends on the machine: the C library's maths (glibc's libm picks, per function, a variant for
# the CPU's instructions, FMA and AVX2 where present; another glibc version may round another way
# in the last bit), which PyBullet's step calls; NumPy's own SIMD kernels. A pile of objects
# dropped on each other (annotate --scenes) amplifies such a bit into another pile. Measured: on
# one AMD EPYC the scene test's pile of six keeps 1 object with glibc's FMA variants and 2 with
# its variants without FMA (GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA).
HWCAPS_TUNABLE = "glibc.cpu.hwcaps="


def _cpu_flags() -> set[str]:
    """The CPU's feature flags as the kernel lists them (empty where there is no /proc/cpuinfo)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith(("flags", "Features")):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def _libm_variant(flags: set[str]) -> str:
    """Which of glibc's x86-64 libm variants this process runs: ``fma`` (FMA and AVX2), ``fma4``,
    ``avx`` or ``sse2``, as its CPU and ``GLIBC_TUNABLES``' hwcaps mask choose; on other machines
    the architecture's one code (``generic``)."""
    if platform.machine() not in ("x86_64", "AMD64"):
        return "generic"
    masked: set[str] = set()
    for part in os.environ.get("GLIBC_TUNABLES", "").split(":"):
        if part.startswith(HWCAPS_TUNABLE):
            masked |= {f.strip().lstrip("-").lower() for f in part[len(HWCAPS_TUNABLE) :].split(",")}
    usable = {f for f in ("fma", "avx2", "fma4", "avx") if f in flags and f not in masked}
    if {"fma", "avx2"} <= usable:
        return "fma"
    for variant in ("fma4", "avx"):
        if variant in usable:
            return variant
    return "sse2"


def _numpy_simd() -> str:
    """The widest SIMD target NumPy's dispatched kernels use here (``AVX512_SKX``, ``AVX2``, ...)."""
    import importlib

    try:  # NumPy's own record of the CPU features its dispatch found (not a public name)
        features = getattr(importlib.import_module("numpy._core._multiarray_umath"), "__cpu_features__", {})
    except ImportError:
        return "unknown"
    for name in ("AVX512_SPR", "AVX512_ICL", "AVX512_SKX", "AVX512F", "AVX2", "AVX", "SSE42", "ASIMD", "VSX"):
        if features.get(name):
            return name
    return "baseline"


@functools.cache
def machine_kind() -> str:
    """One line naming what of this machine can change a label's last bit (see above): the
    architecture, the C library and the variant of its maths, NumPy's SIMD level; e.g. ``x86_64,
    glibc 2.36, libm fma, numpy AVX2``. A run records it in its manifest and a resume on another
    kind says so (labels of chaotic piles may differ between the two)."""
    libc = " ".join(part for part in platform.libc_ver() if part) or "unknown libc"
    return f"{platform.machine()}, {libc}, libm {_libm_variant(_cpu_flags())}, numpy {_numpy_simd()}"
