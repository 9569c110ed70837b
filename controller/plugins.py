"""Plug-ins by entry point: how the registries find robots and tasks, the built-in ones included.

A distribution declares what it brings under an entry-point group of this project:

```toml
[project.entry-points."cheope.robots"]
gantry = "my_gantry:GANTRY"        # a controller.robot_registry.RobotEntry
[project.entry-points."cheope.tasks"]
square = "my_tasks:SQUARE"         # a controller.tasks.registry.TaskEntry
[project.entry-points."cheope.sim_kinematics"]
gantry = "my_gantry:gantry_kinematics"   # (cfg, robot) -> the simulator's kinematics of that robot
[project.entry-points."cheope.analyses"]
gantry = "my_gantry_plots:analyze"       # (cfg, out_dir) -> dict: its plots (cheope analyze)
[project.entry-points."cheope.scene_drawings"]
gantry = "my_gantry:GantryDrawing"       # cfg -> a logs.robot_drawing.RobotDrawing: its 3D scene
[project.entry-points."cheope.experiments"]
square = "my_tasks_experiments:SQUARE"   # a controller.experiments.Experiment, by task kind
[project.entry-points."cheope.commands"]
gantry-home = "my_gantry_cli:HOME"       # a controller.commands.Command: ``cheope gantry-home``
```

The hooks of the sim_kinematics, analyses, scene_drawings and experiments groups are named by robot or task kind and live in the layer that runs them
(the simulator, the analysis tools, the recording's and the viewers' scene), not in the robot's entry: the controller never imports
them, and only the one asked for is loaded (no plotting library for a run).

The papers' robots and tasks are declared the same way, in this project's ``pyproject.toml``, so
a plug-in and a built-in are found alike: ``pip install`` a distribution and ``cheope --robot
gantry`` knows it. A plug-in that cannot be loaded, whose object is not an entry of its
group's kind, or whose name another distribution declares in the same group, stops the lookup
with an error naming the distribution and the entry point (both, for a name declared twice).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Generic, Protocol, TypeVar

from controller.errors import InputError

ROBOTS_GROUP = "cheope.robots"
TASKS_GROUP = "cheope.tasks"
SIM_KINEMATICS_GROUP = "cheope.sim_kinematics"
ANALYSES_GROUP = "cheope.analyses"
EXPERIMENTS_GROUP = "cheope.experiments"
SCENE_DRAWINGS_GROUP = "cheope.scene_drawings"
COMMANDS_GROUP = "cheope.commands"

E = TypeVar("E")


class PluginError(InputError):
    """An entry point that does not load, or does not give what its group asks for."""


def _origin(ep: EntryPoint) -> str:
    dist = ep.dist.name if ep.dist is not None else "an unknown distribution"
    return f"entry point {ep.name} = {ep.value!r} of {dist} (group {ep.group})"


def _load(ep: EntryPoint) -> Any:
    try:
        return ep.load()
    except Exception as err:  # a plug-in's import error, whatever it is: name the plug-in
        raise PluginError(f"{_origin(ep)} does not load: {type(err).__name__}: {err}") from err


def _unique(eps: Iterable[EntryPoint]) -> list[EntryPoint]:
    """``eps``, refused when two distributions declare the same name: which one won depended on the
    order of ``sys.path`` (an outside tester's plug-in named ``cheope`` took the built-in robot's
    simulator kinematics, or its model, with no word), so neither is chosen."""
    seen: dict[str, EntryPoint] = {}
    clashes: set[str] = set()
    for ep in eps:
        first = seen.setdefault(ep.name, ep)
        if first is not ep:
            _refuse(f"{_origin(first)} and {_origin(ep)} declare the same name: uninstall one of them")
            clashes.add(ep.name)  # a listing (``listing_what_loads``) takes neither
    return [ep for name, ep in seen.items() if name not in clashes]


def why_not_loaded(group: str, name: str) -> str:
    """Why no ``name`` of ``group`` is loaded though a distribution declares one: two declare it, or
    it does not load; "" when none declares it. Said where the name is asked for: a plug-in that
    reused the built-in ``cheope`` was met with "robot.kind = 'cheope': must be one of nspu, uru",
    the clash itself left out (an outside tester, 44dbcbc)."""
    eps = list(entry_points(group=group, name=name))
    if len(eps) > 1:
        return f"{_origin(eps[0])} and {_origin(eps[1])} declare the same name: uninstall one of them"
    if eps:
        try:
            _load(eps[0])
        except PluginError as err:
            return str(err)
    return ""


def _refuse(message: str) -> None:
    """A plug-in's error: raised, or kept while the command line lists what loads."""
    global _refusals
    if _skipped is None:
        raise PluginError(message)
    _refusals += 1
    if message not in _skipped:  # each lookup of the group meets it again
        _skipped.append(message)


# While the command line lists the robots, tasks and commands for its parser: what did not load
# (``listing_what_loads``), instead of an error. The parser is built for every command, and one
# broken plug-in ended all of them, ``cheope stop`` and ``--help`` too; the commands that use the
# robots and tasks look them up again, strictly, and meet the error in its one line.
_skipped: list[str] | None = None
_refusals = 0  # every error a listing met, the same one again too: whether a group's scan left one out


@contextmanager
def listing_what_loads() -> Iterator[list[str]]:
    """Lookups inside leave out an entry point that does not load (its error in the list given);
    nothing found so is kept for the lookups after."""
    global _skipped
    before, _skipped = _skipped, []
    try:
        yield _skipped
    finally:
        _skipped = before


def _loaded(ep: EntryPoint, kind: type | None, what: str) -> Any:
    """The entry point's object, checked to be a ``kind`` (callable when None); None when it is
    not and a listing leaves it out (``listing_what_loads``)."""
    try:
        obj = _load(ep)
        if not (isinstance(obj, kind) if kind is not None else callable(obj)):
            raise PluginError(f"{_origin(ep)} is a {type(obj).__name__}, not a {what}")
    except PluginError as err:
        _refuse(str(err))
        return None
    return obj


def discover(group: str, kind: type[E]) -> Iterator[tuple[str, E]]:
    """``(name, object)`` of every entry point in ``group``, each checked to be a ``kind``."""
    for ep in _unique(entry_points(group=group)):
        obj = _loaded(ep, kind, kind.__name__)
        if obj is not None:
            yield ep.name, obj


class _Entry(Protocol):
    @property
    def kind(self) -> str: ...


K = TypeVar("K", bound=_Entry)


class Registry(Generic[K]):
    """The entries of one group: those of the entry points, found at the first lookup, and those
    added by ``register`` (a test, a script), which win over an entry point of the same kind."""

    def __init__(self, group: str, entry_type: type[K], what: str) -> None:
        self.group, self.entry_type, self.what = group, entry_type, what
        self._added: dict[str, K] = {}
        self._found: dict[str, K] | None = None

    def register(self, entry: K) -> None:
        """Add an entry; registering a kind again replaces its entry."""
        self._added[entry.kind] = entry

    def unregister(self, kind: str) -> None:
        self._added.pop(kind, None)

    def rediscover(self) -> None:
        """Read the entry points again at the next lookup (a distribution installed since)."""
        self._found = None

    def entries(self) -> dict[str, K]:
        found = self._found
        if found is None:
            found = {}
            refusals_before = _refusals
            for name, entry in discover(self.group, self.entry_type):
                if name != entry.kind:
                    _refuse(f"entry point {name} of group {self.group} gives the {self.what} {entry.kind!r}")
                    continue
                found[name] = entry
            # kept, unless a listing left something out: the parser asks once per command (20 times),
            # and each scan of every distribution's entry points took seconds in CI's emulated VM
            if _refusals == refusals_before:
                self._found = found
        return {**found, **self._added}

    def entry(self, kind: str) -> K:
        entries = self.entries()
        try:
            return entries[kind]
        except KeyError:
            raise KeyError(f"no {self.what} {kind!r} is registered (known: {', '.join(entries)})") from None


class Hooks:
    """Callables by kind (a robot's) under one entry-point group, and those added by ``register``
    (a script, a test), which win. Only the entry point asked for is loaded."""

    def __init__(self, group: str, what: str, hook_type: type | None = None) -> None:
        """``hook_type``: what each hook must be an instance of (default: any callable)."""
        self.group, self.what, self.hook_type = group, what, hook_type
        self._added: dict[str, Any] = {}

    def register(self, kind: str, hook: Any) -> None:
        self._added[kind] = hook

    def unregister(self, kind: str) -> None:
        self._added.pop(kind, None)

    def all(self) -> dict[str, Any]:
        """Every hook of the group by kind (each entry point loaded and checked), those added winning."""
        found = {
            ep.name: _loaded(ep, self.hook_type, self.what) for ep in _unique(entry_points(group=self.group))
        }
        return {**{k: v for k, v in found.items() if v is not None}, **self._added}

    def get(self, kind: str) -> Any:
        """The hook of ``kind``, or None when no distribution declares one."""
        if kind in self._added:
            return self._added[kind]
        for ep in _unique(entry_points(group=self.group, name=kind)):
            return _loaded(ep, self.hook_type, self.what)
        return None


SIM_KINEMATICS = Hooks(SIM_KINEMATICS_GROUP, "simulator kinematics factory")
ANALYSES = Hooks(ANALYSES_GROUP, "analysis function")
SCENE_DRAWINGS = Hooks(SCENE_DRAWINGS_GROUP, "scene drawing factory")
