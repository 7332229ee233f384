"""The persistent compilation cache (jaxmocap/_cache.py): where it lives, how to turn it off,
and that a second process loads what the first compiled instead of compiling it."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from jaxmocap._cache import cache_dir, host_tag

# A fresh process: imports jaxmocap (which enables the cache), compiles one program, and
# prints the cache folder JAX uses and how many programs it loaded from disk.
_CHILD = """
import json, jax, jax.numpy as jnp
hits = []
jax.monitoring.register_event_listener(lambda name, **kw: hits.append(name) if name.endswith("cache_hits") else None)
import jaxmocap
f = jax.jit(lambda x: jnp.sin(x) @ jnp.cos(x).T + jnp.linalg.inv(x @ x.T + jnp.eye(x.shape[0])))
jax.block_until_ready(f(jnp.ones((7, 7))))
print(json.dumps({"dir": jax.config.jax_compilation_cache_dir, "hits": len(hits)}))
"""


def _child(env: dict) -> dict:
    base = {k: v for k, v in os.environ.items() if k not in ("JAXMOCAP_CACHE", "JAX_COMPILATION_CACHE_DIR")}
    out = subprocess.run(
        [sys.executable, "-c", _CHILD], env={**base, **env}, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_second_process_loads_the_first_ones_programs(tmp_path):
    first = _child({"JAXMOCAP_CACHE": str(tmp_path)})
    folder = tmp_path / host_tag()
    assert Path(first["dir"]) == folder and first["hits"] == 0
    assert any(folder.iterdir()), "nothing was written to the cache folder"
    second = _child({"JAXMOCAP_CACHE": str(tmp_path)})
    assert second["hits"] >= 1


def test_off_leaves_jax_without_a_cache(tmp_path):
    assert _child({"JAXMOCAP_CACHE": "off"})["dir"] is None


def test_a_users_own_jax_cache_wins(tmp_path):
    own = tmp_path / "own"
    got = _child({"JAX_COMPILATION_CACHE_DIR": str(own), "JAXMOCAP_CACHE": str(tmp_path / "ours")})
    assert Path(got["dir"]) == own and not (tmp_path / "ours").exists()


@pytest.mark.parametrize("value", ["off", "0", "none", "False", ""])
def test_off_values(monkeypatch, value):
    monkeypatch.setenv("JAXMOCAP_CACHE", value)
    assert cache_dir() is None


def test_default_folder_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.delenv("JAXMOCAP_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir() == tmp_path / "jaxmocap" / "xla" / host_tag()
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert cache_dir() == Path.home() / ".cache" / "jaxmocap" / "xla" / host_tag()


def test_each_kind_of_cpu_has_its_own_folder(monkeypatch, tmp_path):
    # JAX's key does not name the instruction set: programs for one CPU must not reach another.
    import platform

    tag = host_tag()
    assert tag.startswith(platform.machine()) and len(tag.rsplit("-", 1)[1]) == 8
    monkeypatch.setattr("builtins.open", lambda *a, **k: __import__("io").StringIO("flags\t: fpu sse2 avx512f\n"))
    assert host_tag() != tag


def test_unwritable_folder_warns_and_compiles_anyway(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    base = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    code = "import warnings; warnings.simplefilter('always'); " + _CHILD.replace("\n", "\n", 1)
    out = subprocess.run([sys.executable, "-c", code], env={**base, "JAXMOCAP_CACHE": str(blocker / "x")},
                         capture_output=True, text=True, check=True)  # fmt: skip
    assert "cannot create the compilation cache folder" in out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1])["dir"] is None
