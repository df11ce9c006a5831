"""Import Mitsuba's LLVM variant with a libLLVM it can use, without user set-up.

Dr.Jit's LLVM backend loads libLLVM at run time. Some systems only have old versions
(LLVM 15 crashes in Dr.Jit's JIT), so we look for the newest libLLVM >= 16 and point
DRJIT_LIBLLVM_PATH at it before Mitsuba is imported.
"""

import glob
import os
import re
import sys

MIN_LLVM = 16
VARIANT = "llvm_ad_rgb"
INSTALL_HINT = (
    "Mitsuba's LLVM backend needs libLLVM >= 16. On Debian/Ubuntu: "
    "`sudo apt-get install libllvm19`; on macOS: `brew install llvm`; or set "
    "DRJIT_LIBLLVM_PATH to a libLLVM >= 16 shared library."
)

# Where distributions put versioned libLLVM builds.
_PATTERNS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM.dylib",
    "/usr/local/opt/llvm/lib/libLLVM.dylib",
)


class LlvmNotFound(RuntimeError):
    pass


def _version(path: str) -> int | None:
    """Major version from names like libLLVM-19.so, libLLVM.so.19.1, llvm-17/lib/libLLVM.so."""
    for pattern in (r"libLLVM-(\d+)", r"libLLVM\.so\.(\d+)", r"llvm-(\d+)/", r"llvm@(\d+)/"):
        m = re.search(pattern, path)
        if m:
            return int(m.group(1))
    return None


def find_libllvm(patterns=_PATTERNS) -> str | None:
    """The newest libLLVM >= MIN_LLVM on this machine, or None."""
    prefix = os.environ.get("CONDA_PREFIX")
    if prefix:
        patterns = (*patterns, os.path.join(prefix, "lib", "libLLVM*.so*"))
    found = []
    for pattern in patterns:
        for path in glob.glob(pattern):
            version = _version(os.path.realpath(path)) or _version(path)
            if version is not None and version >= MIN_LLVM and os.path.isfile(path):
                found.append((version, path))
    return max(found)[1] if found else None


def configure_llvm() -> str:
    """Set DRJIT_LIBLLVM_PATH (unless the user already did) and return the library used."""
    preset = os.environ.get("DRJIT_LIBLLVM_PATH")
    if preset:
        if not os.path.isfile(preset):
            raise LlvmNotFound(f"DRJIT_LIBLLVM_PATH={preset} does not exist. {INSTALL_HINT}")
        return preset
    path = find_libllvm()
    if path is None:
        raise LlvmNotFound(f"no libLLVM >= {MIN_LLVM} found. {INSTALL_HINT}")
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def load_mitsuba(threads: int | None = None):
    """Import Mitsuba with the LLVM variant active; `threads` sets Dr.Jit's thread pool."""
    if "mitsuba" not in sys.modules:
        configure_llvm()
    import drjit as dr
    import mitsuba as mi

    if mi.variant() != VARIANT:
        mi.set_variant(VARIANT)
    if threads is not None:
        dr.set_thread_count(threads)
    from . import integrator

    integrator.register()
    return mi
