"""The `jaxmocap` command's quiet XLA log, set before jaxlib loads (it reads the level then).

XLA's C++ log prints "Very slow compile? ... file a bug" banners with E-prefixed lines on
long first compilations: expected for this library's solves, and no error. When this
process is the `jaxmocap` command (the console script or `python -m jaxmocap.cli`) and
neither `--debug` nor the user's own TF_CPP_MIN_LOG_LEVEL says otherwise, only fatal
messages are shown. Importing jaxmocap as a library changes nothing.
"""

import os
import sys
from pathlib import Path

_argv = getattr(sys, "orig_argv", sys.argv)
IS_CLI = Path(sys.argv[0]).name == "jaxmocap" or "jaxmocap.cli" in _argv[1:3]
if IS_CLI and "--debug" not in _argv:
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
