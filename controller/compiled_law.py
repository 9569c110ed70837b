"""The law's modules compiled to C by mypyc, used only while they are their source's compilation.

The step is plain typed Python, and that is what a reader reads, changes and tests. For the loop
it runs compiled: mypyc (the compiler mypy itself ships with) turns the modules of
``COMPILED_MODULES`` into C extensions beside their sources (``python -m
controller.tools.compile_law``, run by ``make setup``), with the same arithmetic on the same
doubles: a session recorded by the interpreted law replays bit for bit on the compiled one and
back (docs/concepts/realtime.md).

A C extension next to its ``.py`` is what Python imports; edit the source and, without this
module, the loop would keep running the old compilation. So on importing ``controller`` this
module compares each source with the SHA-256 recorded for it when it was compiled
(``compiled_law.json``). Any difference, a missing extension or manifest, or
``CHEOPE_LAW=interpreted`` in the environment, and every module of the list is imported from its
source instead (all or none: the compiled modules call each other directly, so a mix would run
old code). ``LAW_BUILD`` says which, and why; the run summaries and ``cheope bench`` print it.

Standard library only: it runs in every process of the controller before anything else.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import json
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

# The cycle's hot modules. The step's: the law, its supervision and smoothing, the tasks and
# Cheope's kinematics. The bus exchange's, in the loop's process beside the step: its frame codecs
# and window (drivers/), and the recorder's encoding of each cycle (logs/cycle_encoding.py). The
# simulator's, per SYNC: the drives, the plant, its mechanics, sensor and contact (sim_backend/);
# in process they took 193 us of a contour cycle with the exchange, 91 us compiled (issue 37).
# Not a base class that plug-ins subclass (sim_backend/plant_kinematics.py): an interpreted class
# cannot inherit from a compiled one. Not the records
# (controller/core/records.py, controller_state.py, cycle_data.py): mypyc compiles their
# dataclass_transform decorator and annotations into something the dataclasses cannot read.
COMPILED_MODULES = (
    "controller.core.cia402",
    "controller.core.contact_guard",
    "controller.core.control_law",
    "controller.core.linalg3",
    "controller.core.periods",
    "controller.core.rotations",
    "controller.core.safety_monitor",
    "controller.core.setpoint_smoothing",
    "controller.robots.cheope.model",
    "controller.robots.performance",
    "controller.tasks.circle_path",
    "controller.tasks.contour_tracking",
    "controller.tasks.path_task",
    "drivers.cyclic_exchange",
    "drivers.pdo_codec",
    "logs.cycle_encoding",
    "sim_backend.contact_disk",
    "sim_backend.device_pdos",
    "sim_backend.drive",
    "sim_backend.fault_injection",
    "sim_backend.force_sensor",
    "sim_backend.mechanics",
    "sim_backend.pdo_parameters",
    "sim_backend.plant",
)
GROUP = "controller.compiled_law"  # mypyc's shared library: controller/compiled_law__mypyc.*.so
MANIFEST = "compiled_law.json"  # beside this file: module -> SHA-256 of the source compiled
ENVIRONMENT = "CHEOPE_LAW"  # "interpreted": the sources, whatever is compiled
ROOT = Path(__file__).resolve().parents[1]  # the directory that holds the package


@dataclass(frozen=True)
class LawBuild:
    compiled: bool
    why: str  # why the law runs interpreted ("" when compiled)
    stale: bool = False  # there is a compilation, but not of these sources: the run warns

    def describe(self) -> str:
        return "compiled (mypyc)" if self.compiled else f"interpreted: {self.why}"


def source_path(module: str, root: Path = ROOT) -> Path:
    return root.joinpath(*module.split(".")).with_suffix(".py")


def extension_path(module: str, root: Path = ROOT) -> Path | None:
    """The module's C extension for this interpreter, None when there is none."""
    base = root.joinpath(*module.split("."))
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        candidate = base.with_name(base.name + suffix)
        if candidate.exists():
            return candidate
    return None


def manifest_path(root: Path = ROOT) -> Path:
    return root / "controller" / MANIFEST


def source_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_manifest(modules: Sequence[str] = COMPILED_MODULES, root: Path = ROOT) -> Path:
    """Record the sources just compiled (the compile tool's last step)."""
    path = manifest_path(root)
    digests = {m: source_digest(source_path(m, root)) for m in modules}
    path.write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n")
    return path


def law_build(
    modules: Sequence[str] = COMPILED_MODULES, root: Path = ROOT, environ: dict[str, str] | None = None
) -> LawBuild:
    """Whether the compiled modules can be used, and why not."""
    env = os.environ if environ is None else environ
    if env.get(ENVIRONMENT, "") == "interpreted":
        return LawBuild(False, f"{ENVIRONMENT}=interpreted")
    missing = [m for m in modules if extension_path(m, root) is None]
    if len(missing) == len(modules):
        return LawBuild(False, "not compiled (python -m controller.tools.compile_law)")
    if missing:
        return LawBuild(False, f"{missing[0]} has no compiled extension for this Python (make compile)", True)
    try:
        recorded = json.loads(manifest_path(root).read_text())
    except (OSError, ValueError):
        return LawBuild(False, f"controller/{MANIFEST} missing or unreadable (make compile)", True)
    for m in modules:
        source = source_path(m, root)
        if recorded.get(m) != source_digest(source):
            return LawBuild(
                False, f"{source.relative_to(root)} changed since it was compiled (make compile)", True
            )
    return LawBuild(True, "")


class InterpretedLaw:
    """Meta path finder: the modules of the list from their sources, ahead of their extensions."""

    def __init__(self, modules: Sequence[str] = COMPILED_MODULES, root: Path = ROOT) -> None:
        self.sources = {m: source_path(m, root) for m in modules}

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        source = self.sources.get(fullname)
        if source is None:
            return None
        return importlib.util.spec_from_file_location(fullname, source)


def run_interpreted(module: str, args: Sequence[str]) -> Any:
    """``python -m module args`` with the law from its sources (``CHEOPE_LAW=interpreted``): what
    its standard output prints as JSON. The bench's figures of the sources beside the compiled law."""
    import subprocess  # only the bench's tools get here, not every process at start-up

    run = subprocess.run(
        [sys.executable, "-m", module, *args],
        capture_output=True,
        text=True,
        env={**os.environ, ENVIRONMENT: "interpreted"},
        check=False,
    )
    if run.returncode != 0:
        raise RuntimeError(
            f"{module} with the law interpreted failed ({run.returncode}): {run.stderr[-2000:]}"
        )
    return json.loads(run.stdout)


def install() -> LawBuild:
    """Decide once per process, before any module of the list is imported (controller/__init__.py)."""
    build = law_build()
    if not build.compiled and not any(isinstance(f, InterpretedLaw) for f in sys.meta_path):
        sys.meta_path.insert(0, InterpretedLaw())
    return build


LAW_BUILD = install()
