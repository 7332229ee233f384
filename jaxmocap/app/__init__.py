"""Application layer: whole pipelines from a lab's files to results on disk.

Each module here chains the library's readers, methods and writers for one job and is
what a command-line verb calls (`jaxmocap.cli` stays thin glue): `multiview` (a lab's
OpenPose folders and calibration to fitted bodies; `multiview_video`: videos through
MediaPipe Pose first), `sweep` (grids of methods and weights over many sequences: chunked
and sharded solves, a resumable store, statistics). Nothing in the library proper imports
from here.
"""

from .sweep import SweepConfigError as SweepConfigError
from .sweep import config_hash as config_hash
from .sweep import load_config as load_config
from .sweep import run_sweep as run_sweep
from .sweep import validate_config as validate_config
from .sweep import variants as variants
from .sweep_report import paired_stats as paired_stats
