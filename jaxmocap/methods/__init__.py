"""Motion-capture methods, each a composition of energy terms solved by `jaxmocap.solve`."""

from . import inertial as inertial
