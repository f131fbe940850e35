"""Dr.Jit / Mitsuba back-end set-up: variant choice and a libLLVM check that cannot abort the process.

Dr.Jit 1.5's CPU back-end (``llvm_ad_rgb``) loads the system's libLLVM at run time and emits
``llvm.maximum`` intrinsics; with LLVM < 17 (Debian 12's default 14/15) code generation hits
``LLVM ERROR: Cannot select ... fmaximum`` and the *whole process* aborts. :func:`check_libllvm` finds
the library Dr.Jit would load, the way Dr.Jit does, without loading it, and raises :class:`LLVMError`
naming the fix. Nothing here imports drjit or mitsuba at module level.
"""

from __future__ import annotations

import glob
import os
import re
import subprocess
import sys
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from render.errors import RenderArgumentError

MIN_LLVM_MAJOR = 17
"""Oldest libLLVM major version Dr.Jit 1.5 can generate code with."""

DEFAULT_VARIANT = "llvm_ad_rgb"
CUDA_VARIANT = "cuda_ad_rgb"

# Where Dr.Jit 1.5 (drjit-core ``jitc_find_library``) looks on Linux once DRJIT_LIBLLVM_PATH is unset and
# ``dlopen("libLLVM.so")`` fails: this glob, sorted, last hit.
_DRJIT_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so.*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so.*",
    "/usr/lib/wsl/lib/libLLVM*.so.*",
)
_STANDARD_LIB_DIRS = (
    "/lib",
    "/usr/lib",
    "/lib64",
    "/usr/lib64",
    "/usr/local/lib",
    "/lib/x86_64-linux-gnu",
    "/usr/lib/x86_64-linux-gnu",
)
_FIX = (
    "install a newer LLVM (Debian 12: `apt-get install -y libllvm19`) or point Dr.Jit at one with "
    "the environment variable DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
)

_checked: dict[str, LLVMLibrary] = {}


class LLVMError(RuntimeError):
    """The libLLVM Dr.Jit would load is missing or too old for Dr.Jit's CPU back-end."""


@dataclass(frozen=True)
class LLVMLibrary:
    """The libLLVM Dr.Jit will load.

    Attributes:
        path: file path (as Dr.Jit would dlopen it).
        major: LLVM major version, or -1 where it could not be told.
        source: how it was found: ``"loaded"``, ``"DRJIT_LIBLLVM_PATH"``, ``"dlopen"`` or ``"glob"``.
    """

    path: str
    major: int
    source: str


def llvm_major_from_name(path: str | os.PathLike) -> int:
    """LLVM major version from a library file name, e.g. ``libLLVM-15.so`` -> 15,
    ``libLLVM.so.19.1`` -> 19, ``libLLVM-14.0.6.so.1`` -> 14; -1 where the name carries none
    (``libLLVM.so``). Symbolic links are not followed (see :func:`llvm_major`)."""
    name = Path(path).name
    m = re.match(r"^libLLVM-(\d+)", name)
    if m:
        return int(m.group(1))
    m = re.match(r"^libLLVM\.so\.(\d+)", name) or re.match(r"^libLLVM\.(\d+)\.dylib", name)
    if m:
        return int(m.group(1))
    return -1


def llvm_major(path: str | os.PathLike) -> int:
    """LLVM major version of a library: from its name, else its resolved link target's name, else by
    asking the library (``LLVMGetVersion``) in a *separate* process; -1 where all fail."""
    major = llvm_major_from_name(path)
    if major < 0 and os.path.exists(path):
        major = llvm_major_from_name(os.path.realpath(path))
    if major < 0 and os.path.exists(path):
        code = (
            "import ctypes, sys; lib = ctypes.CDLL(sys.argv[1]); v = [ctypes.c_uint() for _ in range(3)]; "
            "lib.LLVMGetVersion(*[ctypes.byref(x) for x in v]); print(v[0].value)"
        )
        try:
            out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=60)
            major = int(out.stdout.strip()) if out.returncode == 0 else -1
        except (OSError, ValueError, subprocess.TimeoutExpired):
            major = -1
    return major


def _loaded_libllvm() -> str | None:
    """A libLLVM already mapped into this process (Dr.Jit reuses it), or None."""
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                path = line.split()[-1] if len(line.split()) >= 6 else ""
                if re.search(r"/libLLVM[-.]", path):
                    return path
    except OSError:
        pass
    return None


def _ldconfig_libllvm() -> str | None:
    """What ``dlopen("libLLVM.so")`` would find: LD_LIBRARY_PATH, the ldconfig cache, standard dirs."""
    dirs = [d for d in os.environ.get("LD_LIBRARY_PATH", "").split(":") if d]
    for d in dirs:
        if os.path.exists(os.path.join(d, "libLLVM.so")):
            return os.path.join(d, "libLLVM.so")
    try:
        out = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True, timeout=30).stdout
        for line in out.splitlines():
            parts = line.strip().split(" => ")
            if len(parts) == 2 and parts[0].split()[0] == "libLLVM.so":
                return parts[1].strip()
    except (OSError, subprocess.TimeoutExpired):
        pass
    for d in _STANDARD_LIB_DIRS:
        if os.path.exists(os.path.join(d, "libLLVM.so")):
            return os.path.join(d, "libLLVM.so")
    return None


def _glob_libllvm() -> str | None:
    hits: list[str] = []
    for pattern in _DRJIT_LLVM_GLOBS:
        hits.extend(sorted(glob.glob(pattern)))
    return hits[-1] if hits else None


def find_libllvm() -> LLVMLibrary | None:
    """Resolve the libLLVM Dr.Jit 1.5 would load, in its order, without loading it.

    Order: a libLLVM already loaded in this process; ``DRJIT_LIBLLVM_PATH``; ``dlopen("libLLVM.so")``
    (LD_LIBRARY_PATH, ldconfig cache, standard directories); the glob
    ``/usr/lib/x86_64-linux-gnu/libLLVM*.so.*`` (sorted, last). Returns None where none is found.
    """
    loaded = _loaded_libllvm()
    if loaded:
        return LLVMLibrary(loaded, llvm_major(loaded), "loaded")
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        return LLVMLibrary(env, llvm_major(env), "DRJIT_LIBLLVM_PATH")
    found = _ldconfig_libllvm()
    if found:
        return LLVMLibrary(found, llvm_major(found), "dlopen")
    found = _glob_libllvm()
    if found:
        return LLVMLibrary(found, llvm_major(found), "glob")
    return None


def check_libllvm() -> LLVMLibrary:
    """Refuse a libLLVM Dr.Jit 1.5 cannot use, before Dr.Jit loads it.

    Returns:
        The :class:`LLVMLibrary` found (major >= 17, or unknown: then a warning is issued).

    Raises:
        LLVMError: no libLLVM, a DRJIT_LIBLLVM_PATH that does not exist, or LLVM < 17; the message
            names the fix (``apt-get install libllvm19`` or ``DRJIT_LIBLLVM_PATH``).
    """
    lib = find_libllvm()
    if lib is None:
        raise LLVMError(f"render: Dr.Jit's CPU back-end needs libLLVM >= {MIN_LLVM_MAJOR}, and none was found; {_FIX}.")
    if lib.source == "DRJIT_LIBLLVM_PATH" and not os.path.exists(lib.path):
        raise LLVMError(f"render: DRJIT_LIBLLVM_PATH={lib.path!r} does not exist; {_FIX}.")
    if 0 <= lib.major < MIN_LLVM_MAJOR:
        raise LLVMError(
            f"render: Dr.Jit would load {lib.path} (LLVM {lib.major}, found via {lib.source}); Dr.Jit 1.5 needs "
            f"LLVM >= {MIN_LLVM_MAJOR} and would abort the process ('Cannot select ... fmaximum'). Fix: {_FIX}."
        )
    if lib.major < 0:
        import warnings

        warnings.warn(
            f"render: could not tell the LLVM version of {lib.path}; if the process aborts with "
            f"'Cannot select', {_FIX}",
            RuntimeWarning,
            stacklevel=2,
        )
    return lib


def cuda_available() -> bool:
    """Whether Dr.Jit's CUDA back-end can run here (a GPU and its driver)."""
    import drjit as dr

    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:
        return False


def resolve_variant(device: str = "cpu") -> str:
    """The Mitsuba variant for ``device`` (``"cpu"`` -> ``llvm_ad_rgb``, ``"cuda"`` -> ``cuda_ad_rgb``).

    Checks libLLVM before the CPU variant is first used (:func:`check_libllvm`).

    Raises:
        ValueError: unknown device. LLVMError: unusable libLLVM. RuntimeError: CUDA asked for, absent.
    """
    if device not in ("cpu", "cuda"):
        raise RenderArgumentError(f"resolve_variant: device must be 'cpu' or 'cuda', got {device!r}")
    if device == "cuda":
        if not cuda_available():
            raise RuntimeError("resolve_variant: device='cuda' asked for, but Dr.Jit finds no CUDA device")
        return CUDA_VARIANT
    if DEFAULT_VARIANT not in _checked:
        _checked[DEFAULT_VARIANT] = check_libllvm()
    return DEFAULT_VARIANT


def use_variant(variant: str):
    """Import mitsuba, make ``variant`` current and return the module (cheap where it already is)."""
    import mitsuba as mi

    if mi.variant() != variant:
        mi.set_variant(variant)
    return mi


@contextmanager
def reproducible(enabled: bool = True):
    """Run Dr.Jit's CPU backend on one worker thread inside the block (then restore the thread count).

    Reverse-mode AD accumulates gradients with atomic adds; with several threads their order, and so
    the last bits of a vertex gradient, change from run to run, and a long fit carries that into small
    differences of the fitted head. One thread makes every run bit-for-bit identical, at a higher render
    time (both measured in ``docs/render.md``, "Reproducible runs"). ``enabled=False`` is a no-op.
    """
    if not enabled:
        yield
        return
    import drjit as dr

    previous = dr.thread_count()
    dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(previous)
