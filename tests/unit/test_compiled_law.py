"""The law compiled by mypyc is used only while it is its sources' compilation, and computes what
they compute, bit for bit (controller/compiled_law.py).

The first tests build a small package of their own: a "compiled" module is a file with the
interpreter's extension suffix that is no extension at all, so that importing it fails loudly,
and only the finder's choice of the source lets the import succeed.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.machinery
import json
import os
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

from controller import compiled_law
from controller.compiled_law import (
    COMPILED_MODULES,
    ENVIRONMENT,
    LAW_BUILD,
    InterpretedLaw,
    law_build,
    write_manifest,
)

PACKAGE = "cheope_compiled_law_probe"
MODULES = (f"{PACKAGE}.first", f"{PACKAGE}.second")
SUFFIX = importlib.machinery.EXTENSION_SUFFIXES[0]


@pytest.fixture
def probe(tmp_path: Path) -> Iterator[Path]:
    """tmp_path/PACKAGE with two sources, each beside a broken "extension", and their manifest."""
    package = tmp_path / PACKAGE
    package.mkdir()
    (package / "__init__.py").write_text("")
    for module in MODULES:
        name = module.rsplit(".", 1)[1]
        (package / f"{name}.py").write_text(f"WHERE = 'source of {name}'\n")
        (package / f"{name}{SUFFIX}").write_bytes(b"not an ELF file")
    (tmp_path / "controller").mkdir()  # where the manifest lives
    write_manifest(MODULES, tmp_path)
    sys.path.insert(0, str(tmp_path))
    try:
        yield tmp_path
    finally:
        sys.path.remove(str(tmp_path))
        for name in [m for m in sys.modules if m == PACKAGE or m.startswith(PACKAGE + ".")]:
            del sys.modules[name]


def test_a_compilation_of_the_sources_as_they_are_is_used(probe: Path):
    build = law_build(MODULES, probe, environ={})
    assert build.compiled and not build.stale, build


def test_an_edited_source_is_named_and_the_sources_run_instead(probe: Path):
    (probe / PACKAGE / "second.py").write_text("WHERE = 'edited'\n")
    build = law_build(MODULES, probe, environ={})
    assert not build.compiled and build.stale
    assert f"{PACKAGE}/second.py changed since it was compiled" in build.why


def test_a_missing_extension_or_manifest_is_stale_and_none_at_all_is_not(probe: Path):
    (probe / PACKAGE / f"first{SUFFIX}").unlink()
    build = law_build(MODULES, probe, environ={})
    assert not build.compiled and build.stale and MODULES[0] in build.why
    (probe / PACKAGE / f"second{SUFFIX}").unlink()
    build = law_build(MODULES, probe, environ={})
    assert not build.compiled and not build.stale and "not compiled" in build.why
    for module in ("first", "second"):
        (probe / PACKAGE / f"{module}{SUFFIX}").write_bytes(b"")
    (probe / "controller" / compiled_law.MANIFEST).write_text("{not json")
    build = law_build(MODULES, probe, environ={})
    assert not build.compiled and build.stale and "unreadable" in build.why


def test_the_environment_asks_for_the_sources(probe: Path):
    build = law_build(MODULES, probe, environ={ENVIRONMENT: "interpreted"})
    assert not build.compiled and not build.stale and ENVIRONMENT in build.why


def test_the_finder_imports_every_module_of_the_list_from_its_source(probe: Path):
    with pytest.raises(ImportError):  # without the finder, the "extension" is what Python loads
        importlib.import_module(MODULES[0])
    finder = InterpretedLaw(MODULES, probe)
    sys.meta_path.insert(0, finder)
    try:
        for module in MODULES:
            loaded = importlib.import_module(module)
            name = module.rsplit(".", 1)[1]
            assert (loaded.WHERE, loaded.__file__) == (
                f"source of {name}",
                str(probe / PACKAGE / f"{name}.py"),
            )
        assert finder.find_spec(PACKAGE) is None  # anything else: the usual finders
    finally:
        sys.meta_path.remove(finder)


def test_the_manifest_holds_the_sources_sha256(probe: Path):
    recorded = json.loads((probe / "controller" / compiled_law.MANIFEST).read_text())
    source = probe / PACKAGE / "first.py"
    assert recorded[MODULES[0]] == hashlib.sha256(source.read_bytes()).hexdigest()


# What the compiled law computes: the contour task in simulated time (the loopback devices), every
# cycle's outputs and mode hashed, by this process's law and by the sources in a child process.
_OUTPUTS_DIGEST = """
import hashlib, sys
from controller.assembly import build_law
from controller.compiled_law import LAW_BUILD
from controller.config import load_config, parse_override
from controller.core.cycle_data import cycle_inputs
from controller.shell.loop import SimulatedTime
from sim_backend.loopback import LoopbackExchange

cfg = load_config(None, dict(parse_override(s) for s in ["task.kind=contour"]))
law = build_law(cfg)
sim = SimulatedTime()
exchange = LoopbackExchange(cfg, sim.clock)
state, outputs, digest = law.initial_state(), None, hashlib.sha256()
for k in range(int(sys.argv[1])):
    sim.sleep_until(k * cfg.period_s)
    exchange.send(outputs)
    inputs = cycle_inputs(exchange.collect((k + 1) * cfg.period_s))
    state, outputs, events = law.step(state, inputs, k * cfg.period_s)
    digest.update(repr((outputs.targets, outputs.controlwords, state.mode, state.task_state)).encode())
print(LAW_BUILD.compiled, state.mode.name, digest.hexdigest())
"""


def _digest(cycles: int, law: str) -> tuple[str, str, str]:
    env = {**os.environ, ENVIRONMENT: law}
    run = subprocess.run(
        [sys.executable, "-c", _OUTPUTS_DIGEST, str(cycles)],
        capture_output=True,
        text=True,
        env=env,
        check=True,
        timeout=600,
    )
    compiled, mode, digest = run.stdout.split()
    return compiled, mode, digest


def test_the_compiled_law_computes_what_its_sources_compute_bit_for_bit():
    """Through the approach, the first contact and into the tracking (4 000 cycles, 10 s)."""
    assert LAW_BUILD.compiled, (
        f"the law is not compiled here ({LAW_BUILD.why}): make setup compiles it, make compile again"
    )
    compiled = _digest(4000, "compiled")
    interpreted = _digest(4000, "interpreted")
    assert compiled[0] == "True" and interpreted[0] == "False", (compiled, interpreted)
    assert compiled[1] not in ("FAULT", "DONE"), compiled  # the window is the task at work
    assert compiled[1:] == interpreted[1:]


def test_the_list_is_the_law_s_and_each_of_its_modules_runs_compiled_here():
    if not LAW_BUILD.compiled:
        pytest.skip(f"interpreted here: {LAW_BUILD.why} (the test above says why that fails)")
    for module in COMPILED_MODULES:
        path = importlib.import_module(module).__file__
        assert path is not None and path.endswith(SUFFIX), (module, path)


def test_the_linter_lets_exactly_the_compiled_modules_zip_without_strict():
    """pyproject's per-file B905 exemptions are COMPILED_MODULES' files, no more, no less: a module
    compiled from then on gets its native zips, one no longer compiled gets strict=True back."""
    root = Path(__file__).resolve().parents[2]
    ignores = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["ruff"]["lint"]["per-file-ignores"]
    exempt = {path for path, rules in ignores.items() if "B905" in rules}
    assert exempt == {m.replace(".", "/") + ".py" for m in COMPILED_MODULES}
