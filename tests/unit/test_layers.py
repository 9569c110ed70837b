"""The layers docs/concepts/architecture.md describes, checked on the code's own imports (ast, no import).

- no import cycle, counting every import: top-level, inside functions (lazy) and conditional
  ones (only ``if TYPE_CHECKING:`` blocks, annotations, are left out);
- the pure core (controller/core) imports nothing above itself: only controller/core and
  controller/errors.py of ours, and no I/O library;
- the runtime never imports the tools (controller/tools: bench, experiments, plots), not even
  lazily; only the command line (controller/cli.py) reaches them;
- logs/ does not import the loop shell or the command line; sim_backend/ not the loop or the service;
- matplotlib only in the tools and the robots' analyses;
- no loop between folders; nothing outside a robot's home (controller/robots/<kind>/) imports it.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("controller", "drivers", "sim_backend", "logs")
IO_LIBRARIES = (
    "can",
    "canopen",
    "zenoh",
    "mcap",
    "mcap_protobuf",
    "rerun",
    "matplotlib",
    "socket",
    "subprocess",
)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@cache
def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py")}


def _imported_names(node: ast.Import | ast.ImportFrom) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = node.module or ""
    return [base, *(f"{base}.{a.name}" for a in node.names)]


@cache
def _imports(module: str, top_level_only: bool) -> frozenset[str]:
    """Modules (ours and third-party top-level names) that ``module`` imports."""
    found: set[str] = set()

    def visit(nodes: list[ast.stmt]) -> None:
        for n in nodes:
            if isinstance(n, (ast.Import, ast.ImportFrom)):
                found.update(_imported_names(n))
            elif isinstance(n, ast.If) and "TYPE_CHECKING" in ast.unparse(n.test):
                continue  # annotations only
            elif isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if not top_level_only:
                    visit(n.body)
            else:
                for name in ("body", "orelse", "finalbody"):
                    visit(getattr(n, name, []))
                for h in getattr(n, "handlers", []):
                    visit(h.body)

    visit(ast.parse(_modules()[module].read_text()).body)
    return frozenset(found)


def _ours(names: frozenset[str]) -> set[str]:
    out = set()
    for name in names:
        while name not in _modules() and "." in name:
            name = name.rsplit(".", 1)[0]
        if name in _modules():
            out.add(name)
    return out


def _in(module: str, *prefixes: str) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def test_no_import_cycles():
    graph = {m: _ours(_imports(m, False)) - {m} for m in _modules()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def walk(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                raise AssertionError("import cycle: " + " -> ".join([*stack[stack.index(n) :], n]))
            if n not in state:
                walk(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            walk(m)


def test_the_core_imports_nothing_above_itself_and_does_no_io():
    for m in _modules():
        if not _in(m, "controller.core"):
            continue
        names = _imports(m, False)
        bad = [n for n in _ours(names) if not _in(n, "controller.core", "controller.errors")]
        bad += [n for n in names if n.split(".")[0] in IO_LIBRARIES]
        assert not bad, f"{m} imports {bad}"


def test_only_the_command_line_reaches_the_tools():
    for m in _modules():
        if _in(m, "controller.tools") or m == "controller.cli":
            continue
        bad = [n for n in _ours(_imports(m, False)) if _in(n, "controller.tools")]
        assert not bad, f"{m} (runtime) imports the tools {bad}"


def test_recordings_and_simulator_stay_off_the_loop_shell():
    for m in _modules():
        names = _ours(_imports(m, False))
        if _in(m, "logs"):
            assert not [n for n in names if _in(n, "controller.shell", "controller.cli")], m
        if _in(m, "sim_backend"):
            assert not [n for n in names if _in(n, "controller.shell.loop", "controller.shell.service")], m


def _robot_home(module: str) -> str | None:
    """``controller.robots.<kind>`` for a module of a robot's home (controller/robots/<kind>/), else None."""
    parts = module.split(".")
    return ".".join(parts[:3]) if parts[:2] == ["controller", "robots"] and len(parts) > 3 else None


def test_matplotlib_only_in_the_tools_and_the_robots_analyses():
    """Plots are tools: the tools and each robot's analysis (``cheope analyze``, by entry point)."""
    for m in _modules():
        if "matplotlib" in {n.split(".")[0] for n in _imports(m, False)}:
            assert _in(m, "controller.tools") or (_robot_home(m) is not None and m.endswith(".analysis")), (
                f"{m} imports matplotlib"
            )


def test_nothing_outside_a_robots_home_names_it():
    """A robot lives in its home, controller/robots/<kind>/; the rest of the product reaches it through
    the ports and the entry points (pyproject.toml), never by importing it."""
    for m in _modules():
        homes = {_robot_home(n) for n in _ours(_imports(m, False))} - {None, _robot_home(m)}
        assert not homes, f"{m} imports the robot home(s) {sorted(h for h in homes if h)}"


def _room(module: str) -> str:
    """A module's room: its folder (controller/core, logs, ...), or the module itself when it stands at
    the top of controller/ (config.py, errors.py, cli.py each a room of its own)."""
    parts = module.split(".")
    if (parts[0] == "controller" and len(parts) > 2) or (parts[0] != "controller" and len(parts) > 1):
        return ".".join(parts[:2] if parts[0] == "controller" else parts[:1])
    return module


def test_no_loop_between_folders():
    """Folders import each other one way: a loop (the shell reads the recorder, logs drew with the
    simulator's plant, the simulator took the shell's scheduling) ties three folders into one."""
    graph: dict[str, set[str]] = {}
    for m in _modules():
        graph.setdefault(_room(m), set()).update(
            _room(n) for n in _ours(_imports(m, False)) if _room(n) != _room(m)
        )
    state: dict[str, int] = {}

    def walk(room: str, path: list[str]) -> None:
        state[room] = 1
        for n in sorted(graph.get(room, ())):
            if state.get(n) == 1:
                raise AssertionError("folders in a loop: " + " -> ".join([*path[path.index(n) :], n]))
            if n not in state:
                walk(n, [*path, n])
        state[room] = 2

    for room in sorted(graph):
        if room not in state:
            walk(room, [room])
