"""Shared test configuration: strict float64 JAX, a persistent compilation cache, data paths,
and ``bifid_cli``: the ``bifid`` command run in-process as a user runs it."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import pytest

jax.config.update("jax_enable_x64", True)
# Compiled XLA programs are cached across test runs (CI runs the suite once per clone,
# a developer many times): keys include the jaxlib version, so stale hits cannot occur.
_CACHE = Path(__file__).resolve().parents[1] / ".jax_cache"
os.environ.setdefault("BIFID_JAX_CACHE", str(_CACHE))  # the CLI's cache, in-process too
jax.config.update("jax_compilation_cache_dir", os.environ["BIFID_JAX_CACHE"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--runslow", action="store_true", default=False, help="run tests/slow")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow (make test-slow)")
    for item in items:
        if "slow" in item.keywords or "/slow/" in str(item.fspath):
            item.add_marker(skip)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path to ../shared/data (real measurements); tests using it skip if it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data not available")
    return SHARED_DATA


@dataclass
class CliResult:
    """What one ``bifid`` invocation produced: exit code, stdout, stderr."""

    code: int
    stdout: str
    stderr: str

    @property
    def json(self) -> Any:
        """The one JSON object printed on stdout (``--json``)."""
        return json.loads(self.stdout)


@pytest.fixture
def bifid_cli(capsys: pytest.CaptureFixture[str]):
    """Run ``bifid ARGS...`` in-process (``bifid.cli.main``) and return a :class:`CliResult`.

    In-process keeps JAX's compiled functions across calls, so a test can run many
    commands on small problems quickly; the exit code is the one the console script gives.
    """
    from bifid.cli import main

    def run(*args: Any) -> CliResult:
        capsys.readouterr()
        try:
            main([str(a) for a in args])
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        out, err = capsys.readouterr()
        return CliResult(code, out, err)

    return run
