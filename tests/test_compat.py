"""The private internals jaxmocap reaches into (`jaxmocap._compat`) still exist.

If one of these fails after an upgrade, the installed version differs from the one the
hooks were written for (named in the message): fix `jaxmocap/_compat.py`, nothing else.
"""

import importlib.metadata

import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import pytest

from jaxmocap import _compat


def _versions(name):
    return f"installed {name} {importlib.metadata.version(name)}, hooks written for {_compat.TESTED_WITH[name]}"


def test_optimistix_result_codes():
    codes = {_compat.SUCCESSFUL, _compat.MAX_STEPS, _compat.DIVERGENCE}
    assert len(codes) == 3, _versions("optimistix")
    assert _compat.result_message(_compat.SUCCESSFUL) == "", _versions("optimistix")
    assert "maximum number of steps" in _compat.result_message(_compat.MAX_STEPS), _versions("optimistix")
    # A real solve's result reads back through the same hook.
    sol = optx.least_squares(lambda y, _: y - 1.0, optx.LevenbergMarquardt(1e-8, 1e-8), jnp.zeros(2), throw=False)
    assert int(np.asarray(_compat.result_code(sol.result))) == _compat.SUCCESSFUL, _versions("optimistix")


def test_optimistix_damped_operator():
    J = jnp.array([[1.0, 2.0], [0.0, 3.0]])
    op = _compat.damped_operator(lx.MatrixLinearOperator(J), jnp.asarray(4.0))
    y = jnp.array([1.0, -1.0])
    Jy, dy = op(y)
    np.testing.assert_allclose(Jy, J @ y, err_msg=_versions("optimistix"))
    np.testing.assert_allclose(dy, 2.0 * y, err_msg=_versions("optimistix"))  # sqrt(lambda) y


def test_mjx_contacts():
    import mujoco  # a pinned dependency: imported, never skipped
    from mujoco import mjx

    xml = """<mujoco><worldbody><geom type="plane" size="5 5 .1"/>
      <body pos="0 0 0.05"><freejoint/><geom type="sphere" size="0.1"/></body></worldbody></mujoco>"""
    model = mjx.put_model(mujoco.MjModel.from_xml_string(xml))
    data = mjx.collision(model, mjx.kinematics(model, mjx.make_data(model)))
    contact = _compat.mjx_contacts(data)
    assert float(np.min(np.asarray(contact.dist))) == pytest.approx(-0.05, abs=1e-4), _versions("mujoco-mjx")


def test_jax_cpu_backend_flag():
    # `_threads` warns when JAX's CPU backend started before `import jaxmocap`; the flag it
    # reads is private (`jax._src.xla_bridge._backends`) and reads False if it moved.
    jnp.zeros(1).block_until_ready()  # the CPU backend runs from here on
    assert _compat.cpu_backend_started(), "jax._src.xla_bridge._backends moved: fix _compat.cpu_backend_started"
