"""Energy terms as residual functions for `jaxmocap.solve` (one module per sensor kind)."""

from . import imu as imu
