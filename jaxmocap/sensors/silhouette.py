"""Moved to `jaxmocap.geometry.raster`; this alias goes in the next release."""

from ..geometry.raster import BACKGROUND as BACKGROUND
from ..geometry.raster import FLOOR as FLOOR
from ..geometry.raster import rasterize as rasterize
from ..geometry.raster import rasterize_views as rasterize_views
from ..geometry.raster import window_for as window_for
