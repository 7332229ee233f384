"""jaxmocap: human motion capture by model-based optimisation, in JAX."""

from . import _cli_env  # noqa: F401  first: the command line's XLA log level, read when jaxlib loads
from ._threads import MIN_CPU_THREADS as MIN_CPU_THREADS  # first: it must precede JAX's CPU backend
from ._cache import enable_compilation_cache as enable_compilation_cache

from . import motion as motion
from . import rotation as rotation
from .body import SMPL_JOINT_NAMES as SMPL_JOINT_NAMES
from .body import SMPL_PARENTS as SMPL_PARENTS
from .body import Body as Body
from .body import BodyFileError as BodyFileError
from .body import BodyOutput as BodyOutput
from .body import default_body as default_body
from .body import forward as forward
from .body import load_body as load_body
from .body import save_body as save_body

enable_compilation_cache()  # compiled programs kept on disk across processes (jaxmocap/_cache.py)

__version__ = "0.1.0"

# Heavier subpackages (MuJoCo, trimesh, matplotlib) load on first use: `jaxmocap.physics`.
_LAZY = (
    "energies",
    "formats",
    "geometry",
    "learned",
    "methods",
    "metrics",
    "objects",
    "physics",
    "priors",
    "sensors",
    "solve",
    "viz",
)


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'jaxmocap' has no attribute {name!r}")
