"""JAX's persistent compilation cache, on by default: a program compiles once per machine.

A solve compiles for tens of seconds and then runs in a fraction of one; without a disk
cache every new process (a CLI call, an experiment, a re-run after changing a weight) pays
that again. `import jaxmocap` points JAX's cache at a per-user folder:

- ``$JAXMOCAP_CACHE`` if set: a folder, or ``off`` (also ``0``, ``none``, ``false``, empty)
  to leave JAX's cache as it is;
- else ``$XDG_CACHE_HOME/jaxmocap/xla`` (``~/.cache/jaxmocap/xla`` without XDG_CACHE_HOME);

each with a subfolder per kind of CPU (below).

A cache folder the user configured in JAX itself (``JAX_COMPILATION_CACHE_DIR`` or
``jax.config.update("jax_compilation_cache_dir", ...)`` before the import) is left alone.
Entries are keyed by the program, the JAX/jaxlib versions, the device and the XLA flags, so
a stale entry is never used; deleting the folder is always safe. JAX's key does not name
the CPU's instruction set, and a CPU program compiled where AVX-512 exists would crash
where it does not, so each kind of CPU gets its own subfolder (`host_tag()`; a home folder
shared by a cluster's nodes is then safe). Every compiled program is stored: the methods'
many small ones add up to seconds per run.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["MIN_COMPILE_S", "cache_dir", "enable_compilation_cache", "host_tag"]

#: Programs compiling faster than this are not written to disk (JAX's default is 1 s).
MIN_COMPILE_S = 0.0
_OFF = {"", "0", "off", "none", "false", "no"}


def host_tag() -> str:
    """This machine's architecture and a hash of its CPU's feature flags, e.g. 'x86_64-3f2a9c01'."""
    import hashlib
    import platform

    flags = ""
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((line for line in f if line.startswith(("flags", "Features"))), "")
    except OSError:  # not Linux: the processor's name stands in
        flags = platform.processor()
    return f"{platform.machine() or 'cpu'}-{hashlib.sha256(flags.encode()).hexdigest()[:8]}"


def cache_dir() -> Path | None:
    """The folder jaxmocap uses for compiled programs (None: disabled by JAXMOCAP_CACHE)."""
    value = os.environ.get("JAXMOCAP_CACHE")
    if value is not None:
        return None if value.strip().lower() in _OFF else Path(value).expanduser() / host_tag()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxmocap" / "xla" / host_tag()


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Store compiled programs in `path` (default: `cache_dir()`); returns the folder used.

    Does nothing (returns the folder JAX already uses, or None) when the user configured
    JAX's cache themselves or disabled jaxmocap's with JAXMOCAP_CACHE=off and no `path`.
    A folder that cannot be created disables the cache with a warning rather than failing.
    """
    import jax

    configured = jax.config.jax_compilation_cache_dir
    if path is None and configured:
        return Path(configured)
    folder = Path(path).expanduser() if path is not None else cache_dir()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        import warnings

        warnings.warn(
            f"jaxmocap: cannot create the compilation cache folder {folder} ({error}); programs will be compiled "
            "anew in each process. Set JAXMOCAP_CACHE to a writable folder, or to 'off'.",
            RuntimeWarning, stacklevel=2,
        )  # fmt: skip
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_S)
    return folder
