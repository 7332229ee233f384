"""Energy terms as residual functions for `jaxmocap.solve` (one module per sensor kind;
`posed`: the posed body and data the terms of one problem share)."""

from . import imu as imu
from . import posed as posed
