"""geosynth.core.config owns every environment variable geosynth reads or sets (issue 33)."""

import ast
import os
from pathlib import Path

import pytest

from geosynth.core import config

PACKAGE = Path(__file__).resolve().parents[1] / "geosynth"


def test_only_config_touches_the_environment():
    """No module but geosynth.core.config reads or sets os.environ (or calls os.getenv / putenv)."""
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "config.py" and path.parent == PACKAGE / "core":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Attribute) and node.attr in ("environ", "getenv", "putenv", "unsetenv") \
                    and isinstance(node.value, ast.Name) and node.value.id == "os":
                offenders.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}")
    assert not offenders, offenders


def test_every_variable_is_in_the_table():
    """Each variable config.py reads or sets appears in its docstring's table."""
    doc = config.__doc__
    for name in (config.ENV_VERBOSE, config.ENV_HOST_THREADS, config.ENV_MEMORY_LIMIT, "XDG_CACHE_HOME",
                 "POCL_AFFINITY", "POCL_SIGFPE_HANDLER", "OMP_WAIT_POLICY", "POCL_*", config.ENV_NUMPY_FEATURES):
        assert f"``{name}``" in doc, name


def test_verbose_setting_and_variable(monkeypatch):
    monkeypatch.delenv(config.ENV_VERBOSE, raising=False)
    assert not config.verbose()
    for text, on in (("1", True), ("yes", True), ("0", False), ("false", False), ("", False)):
        monkeypatch.setenv(config.ENV_VERBOSE, text)
        assert config.verbose() is on
    try:
        config.set_verbose(False)
        monkeypatch.setenv(config.ENV_VERBOSE, "1")
        assert not config.verbose()  # the setting wins
        config.set_verbose(True)
        monkeypatch.delenv(config.ENV_VERBOSE)
        assert config.verbose()
    finally:
        config.set_verbose(None)
    assert not config.verbose()


def test_settings_read_and_refused(monkeypatch, tmp_path):
    monkeypatch.delenv(config.ENV_HOST_THREADS, raising=False)
    assert config.host_threads_setting() is None
    monkeypatch.setenv(config.ENV_HOST_THREADS, "3")
    assert config.host_threads_setting() == 3
    for bad in ("0", "-2", "two", "1.5"):
        monkeypatch.setenv(config.ENV_HOST_THREADS, bad)
        with pytest.raises(ValueError, match=f"{config.ENV_HOST_THREADS} must be a whole number >= 1, got '{bad}'"):
            config.host_threads_setting()
    monkeypatch.setenv(config.ENV_MEMORY_LIMIT, " 2G ")
    assert config.memory_limit_setting() == "2G"
    monkeypatch.setenv(config.ENV_MEMORY_LIMIT, "  ")
    assert config.memory_limit_setting() is None
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert config.cache_root() == os.path.join(str(tmp_path), "geosynth")
    monkeypatch.setenv("POCL_DEVICES", "cpu")
    monkeypatch.setenv("POCL_CACHE_DIR", str(tmp_path))  # where it caches: not part of the key
    keys = [k for k, _ in config.pocl_settings()]
    assert "POCL_DEVICES" in keys and "POCL_CACHE_DIR" not in keys and keys == sorted(keys)


_STATE_CALLS = {("threading", "Lock"), ("threading", "RLock"), ("threading", "local"), ("threading", "Semaphore"),
                ("threading", "Event"), ("threading", "Condition")}
_CLI_ONLY = {"cli.py", "_launch.py"}  # the command line's own signal lists


def _makes_state(value) -> bool:
    """A module-level value that is process-wide state: an empty dict / set / list, or a lock or
    thread-local made by the threading module."""
    if (isinstance(value, ast.Dict) and not value.keys) or (isinstance(value, ast.List) and not value.elts):
        return True
    if isinstance(value, ast.Call) and isinstance(value.func, ast.Name) and value.func.id in ("dict", "set", "list") \
            and not value.args:
        return True
    return (isinstance(value, ast.Call) and isinstance(value.func, ast.Attribute)
            and isinstance(value.func.value, ast.Name) and (value.func.value.id, value.func.attr) in _STATE_CALLS)


def test_process_wide_caches_and_locks_are_made_in_config():
    """Every module-level cache (an empty container filled at run time) and lock is made in
    geosynth.core.config and named in its table; the modules that use one hold a reference."""
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if (path.name == "config.py" and path.parent == PACKAGE / "core") or path.name in _CLI_ONLY:
            continue
        for node in ast.parse(path.read_text(), str(path)).body:
            value = node.value if isinstance(node, (ast.Assign, ast.AnnAssign)) else None
            if value is not None and _makes_state(value):
                offenders.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}")
    assert not offenders, offenders
    doc = config.__doc__
    for name in ("OPENCL_CONTEXTS", "WARP_INIT_NOTES", "HOST_POOLS", "HOST_POOL_LOCK", "HOST_LOAD_LOCK", "HOST_LAUNCHED",
                 "HOST_SHARE", "HOST_WARP_DTYPES", "HOST_WARP_STATE", "BLEND_TABLES", "PATCH_SEARCH_LOCK",
                 "TILE_MATCHERS", "TILE_LOCK", "INPUT_PATHS"):
        assert f"``{name}``" in doc and hasattr(config, name), name


def _python(code: str, env: dict | None = None) -> str:
    import subprocess
    import sys

    full = {k: v for k, v in os.environ.items() if k != config.ENV_NUMPY_FEATURES}
    full.update(env or {})
    done = subprocess.run([sys.executable, "-W", "always::RuntimeWarning", "-c", code], capture_output=True,
                          text=True, env=full, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout + done.stderr


def _has_avx512() -> bool:
    import numpy as np

    return any(np._core._multiarray_umath.__cpu_features__.get(k) for k in ("X86_V4", "AVX512F"))


def test_import_geosynth_keeps_numpy_off_its_avx512_code():
    """``import geosynth`` before NumPy: NumPy's float64 exp, log and arctan2 give the bits
    they give with its AVX-512 code off (any CPU's); a user's own setting wins (here an empty
    one, which on an AVX-512 CPU gives other bits)."""
    digest = ("import numpy as np, hashlib; x = np.linspace(-20, 20, 100_001); "
              "print(hashlib.sha1(np.exp(x).tobytes() + np.log(np.abs(x) + 1).tobytes() "
              "+ np.arctan2(x, x[::-1]).tobytes()).hexdigest())")
    ours = _python("import os, geosynth; print(os.environ['NPY_DISABLE_CPU_FEATURES']); " + digest).split()
    assert " ".join(ours[:-1]) in config.NUMPY_AVX512.values()
    off = _python(digest, {config.ENV_NUMPY_FEATURES: config.NUMPY_AVX512["new"] + " " + config.NUMPY_AVX512["old"]})
    assert ours[-1] == off.split()[-1]
    users = _python("import os, geosynth; print(repr(os.environ['NPY_DISABLE_CPU_FEATURES'])); " + digest,
                    {config.ENV_NUMPY_FEATURES: ""}).split()
    assert users[0] == "''"
    if _has_avx512():
        assert users[-1] != ours[-1]


def test_numpy_loaded_first_on_an_avx512_cpu_is_named_in_a_warning():
    out = _python("import numpy, geosynth")
    if _has_avx512():
        assert "NumPy was imported before geosynth" in out and "AVX-512" in out
    else:
        assert "NumPy was imported before geosynth" not in out
