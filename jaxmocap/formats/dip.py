"""DIP-IMU pickles (Huang ch. 6): the dataset's layout, ours (`sensors.save_dip`) or the original.

A dict with imu_ori (N, 17, 3, 3), imu_acc (N, 17, 3) and gt (N, 72) SMPL poses; the
original files are Python-2 pickles (read as latin1).
"""

from __future__ import annotations

import numpy as np

from .._files import load_array_pickle
from ..motion.skeleton import MotionFileError, check_file

__all__ = ["load_dip"]


def load_dip(path) -> dict:
    """Read a DIP-IMU-layout pickle (ours or the original; latin1 for Python-2 pickles).

    Raises:
        FileNotFoundError, or MotionFileError (a ValueError) naming the file when it is not
        a DIP pickle. Only numpy arrays and plain containers are unpickled.
    """
    path = check_file(path)
    try:
        data = load_array_pickle(path)
    except Exception as e:  # a non-pickle or a damaged one can raise almost anything
        raise MotionFileError(
            f"{path}: not a DIP-IMU pickle ({type(e).__name__}: {e}); expected a pickled dict "
            "with imu_ori, imu_acc and gt."
        ) from e
    if not isinstance(data, dict):
        raise MotionFileError(f"{path}: the pickle holds a {type(data).__name__}, not a DIP-IMU dict.")
    for key, shape in (("imu_ori", (17, 3, 3)), ("imu_acc", (17, 3)), ("gt", (72,))):
        if key not in data or np.shape(data[key])[1:] != shape:
            raise MotionFileError(f"{path}: '{key}' missing or not (N, {', '.join(map(str, shape))}).")
    return data
