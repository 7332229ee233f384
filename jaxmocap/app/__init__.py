"""Applications built on the methods: sweeps (grids, sharded chunked solves, resumable store, statistics)."""

from .sweep import SweepConfigError as SweepConfigError
from .sweep import config_hash as config_hash
from .sweep import load_config as load_config
from .sweep import run_sweep as run_sweep
from .sweep import validate_config as validate_config
from .sweep import variants as variants
from .sweep_report import paired_stats as paired_stats
