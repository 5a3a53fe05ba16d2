"""geosynth.config owns every environment variable geosynth reads or sets (issue 33)."""

import ast
import os
from pathlib import Path

import pytest

from geosynth import config

PACKAGE = Path(__file__).resolve().parents[1] / "geosynth"


def test_only_config_touches_the_environment():
    """No module but geosynth.config reads or sets os.environ (or calls os.getenv / putenv)."""
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "config.py" and path.parent == PACKAGE:
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
                 "POCL_AFFINITY", "POCL_SIGFPE_HANDLER", "OMP_WAIT_POLICY", "POCL_*"):
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
