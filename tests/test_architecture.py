"""The house rules of DESIGN.md, checked on the source: no import circles, layers import downwards only.

Every import statement counts, also those inside functions (a lazy import still makes two modules
depend on each other). Imports are read with `ast`, so nothing is executed.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("activelearn", "simulator")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {
        _module_name(path): path
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
        if "__pycache__" not in path.parts
    }


MODULES = _modules()
# What a campaign is made of besides its strategies (each room one job; see the README's map).
_CAMPAIGN_ROOMS = (
    "campaign", "fitting", "evaluation", "budget", "run_log", "proposals", "admission", "round_figure",
    "oracles", "collection", "prior", "state", "lock", "asktell", "safety",
)  # fmt: skip
_STRATEGY_ROOMS = (
    "strategy", "history", "space_filling", "function_space", "greedy_sampling", "lcmd", "regressor_space",
    "fisher", "acquisition",
)  # fmt: skip


def _imports(name: str, path: Path) -> Iterator[tuple[str, int]]:
    """(imported module, line) for every import statement of a module, resolved to project modules."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_package = path.name == "__init__.py"
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative import: resolve against this module's package
                base = name.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            for alias in node.names:
                child = f"{module}.{alias.name}"
                yield (child if child in MODULES else module), node.lineno


def _project_edges() -> dict[str, set[str]]:
    edges: dict[str, set[str]] = {name: set() for name in MODULES}
    for name, path in MODULES.items():
        for target, _ in _imports(name, path):
            while target and target not in MODULES:  # `import a.b.c` where c is an attribute
                target = target.rpartition(".")[0]
            if target and target != name:
                edges[name].add(target)
    return edges


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_the_scan_sees_the_known_edges():
    # Guards the checker itself: if it resolved nothing, every rule below would pass vacuously.
    edges = _project_edges()
    assert "activelearn.numerics.arch" in edges["activelearn.config.model"]
    assert "activelearn.loop.acquisition" in edges["activelearn.loop.campaign"]
    assert "activelearn.loop.fitting" in edges["activelearn.loop.campaign"]
    assert "activelearn.cli.common" in edges["activelearn.cli.campaign"]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_circles():
    assert _cycles(_project_edges()) == []


def _violations(importers: str, forbidden: tuple[str, ...]) -> list[str]:
    bad = []
    for name, path in MODULES.items():
        if not (name == importers or name.startswith(importers + ".")):
            continue
        for target, line in _imports(name, path):
            if any(target == f or target.startswith(f + ".") for f in forbidden):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    return bad


@pytest.mark.parametrize(
    ("importers", "forbidden"),
    [
        ("simulator", ("activelearn",)),
        (
            "activelearn.numerics",
            ("activelearn.loop", "activelearn.studies", "activelearn.cli", "activelearn.plots"),
        ),
        ("activelearn.loop", ("activelearn.studies", "activelearn.cli")),
        # the ground floor: the config names strategies and metrics through `names`, not the loop
        (
            "activelearn.config",
            ("activelearn.loop", "activelearn.studies", "activelearn.cli", "activelearn.plots"),
        ),
        ("activelearn.data", ("activelearn.loop", "activelearn.studies", "activelearn.numerics")),
        # a log on a grid serves the simulator's replay (fidelity) and the surrogate's (loop.benchmark)
        ("activelearn.replay", ("activelearn.loop", "activelearn.studies", "activelearn.numerics",
                                "activelearn.cli", "activelearn.fidelity", "simulator")),
        ("activelearn.fidelity", ("activelearn.loop", "activelearn.studies", "activelearn.numerics",
                                  "activelearn.cli")),
        ("activelearn.plots", ("activelearn.loop", "activelearn.studies", "activelearn.numerics")),
        # the names everything shares import nothing of the project (the CLI's help reads them cheaply)
        ("activelearn.names", ("activelearn", "simulator")),
        # the campaign's rooms serve the campaign; none reaches back into it
        *[
            (f"activelearn.loop.{room}", ("activelearn.loop.campaign", "activelearn.loop.asktell"))
            for room in _CAMPAIGN_ROOMS[1:8]
        ],
        # strategies only score a pool: they know no campaign, oracle, model store or tracker
        *[
            (f"activelearn.loop.{room}", tuple(f"activelearn.loop.{other}" for other in _CAMPAIGN_ROOMS))
            for room in _STRATEGY_ROOMS
        ],
    ],
)
def test_layers_import_downwards(importers, forbidden):
    assert _violations(importers, forbidden) == []


def test_the_numerics_never_run_mujoco():
    # `against_simulator` lives a floor up (activelearn.loop.benchmark): the numerics may read the
    # simulator's maneuver definitions and datasheet, never drive its MuJoCo model.
    runs_mujoco = {
        "collect", "Vehicle", "twin_vehicle", "build_vehicle", "NoiseConfig", "add_noise", "model_xml"
    }
    bad = []
    for name, path in MODULES.items():
        if not name.startswith("activelearn.numerics"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "simulator" for a in node.names):
                bad.append(f"{name}:{node.lineno} imports the whole simulator")
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("simulator"):
                module = node.module or ""
                if module in ("simulator.collect", "simulator.vehicle", "simulator.twin", "simulator.build",
                              "simulator.tyre_car", "simulator.tyre_kernel"):
                    bad.append(f"{name}:{node.lineno} imports {module}")
                bad += [f"{name}:{node.lineno} imports {a.name}" for a in node.names if a.name in runs_mujoco]
    assert bad == []


def test_the_loop_names_no_strategy():
    # Every strategy is called through one interface (Strategy.pick, round_metrics): outside the
    # strategy rooms no module of the loop or the studies names one, by its name or its class.
    from activelearn.names import STRATEGY_NAMES

    rooms = {f"activelearn.loop.{room}" for room in _STRATEGY_ROOMS}
    bad = []
    for name, path in MODULES.items():
        if not name.startswith(("activelearn.loop", "activelearn.studies")) or name in rooms:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and node.value in STRATEGY_NAMES:
                bad.append(f"{name}:{node.lineno} names {node.value!r}")
            elif isinstance(node, ast.Name | ast.alias):
                ident = node.id if isinstance(node, ast.Name) else node.name
                if ident.endswith("Strategy") and ident != "Strategy":
                    bad.append(f"{name}:{node.lineno} names {ident}")
    assert bad == []


def _keys_built(tree: ast.AST) -> set[str]:
    """String keys a module writes into mappings: dict displays, `d["k"] = ...`, `update(k=...)`,
    `dict(k=...)`, `replace(k=...)` and `setdefault("k", ...)`."""
    keys: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            keys |= {k.value for k in node.keys if isinstance(k, ast.Constant) and isinstance(k.value, str)}
        elif isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Store):
            if isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, str):
                keys.add(node.slice.value)
        elif isinstance(node, ast.Call):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if called in ("update", "dict", "replace"):
                keys |= {k.arg for k in node.keywords if k.arg}
            elif called == "setdefault" and node.args and isinstance(node.args[0], ast.Constant):
                keys.add(str(node.args[0].value))
    return keys


def _keys_read(tree: ast.AST) -> set[str]:
    """String keys a module reads out of mappings: `d["k"]`, `d.get("k")`, `d.pop("k")`, `setdefault`."""
    keys: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Load):
            if isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, str):
                keys.add(node.slice.value)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.args:
            first = node.args[0]
            if node.func.attr in ("get", "pop", "setdefault") and isinstance(first, ast.Constant):
                if isinstance(first.value, str):
                    keys.add(first.value)
    return keys


def _keys_built_for_strategies(sources: dict[str, str]) -> list[str]:
    """Keys a loop module outside the strategy rooms builds and a strategy room reads, but for round
    metrics (names.py's, and every key the evaluation room builds: what a round logs for every
    strategy, which strategies read from `History.rounds`). `sources`: module name -> source."""
    from activelearn.names import METRICS

    rooms = {f"activelearn.loop.{room}" for room in _STRATEGY_ROOMS}
    trees = {name: ast.parse(source) for name, source in sources.items()}
    read = set().union(*(_keys_read(tree) for name, tree in trees.items() if name in rooms))
    metrics = set(METRICS) | _keys_built(trees.get("activelearn.loop.evaluation", ast.Module([], [])))
    return sorted(
        f"{name} builds {key!r}"
        for name, tree in trees.items()
        if name not in rooms and name != "activelearn.loop.evaluation"
        for key in (_keys_built(tree) & read) - metrics
    )


def test_the_key_scan_sees_a_key_built_for_one_strategy():
    # Guards the check below: the coupling it forbids (a context key only `auto` reads) is found.
    sources = {
        "activelearn.loop.campaign": 'context = {"round": 1}\ncontext["warm_start"] = 1.0\n',
        "activelearn.loop.acquisition": 'if pool.context.get("warm_start") and r["round"]: pass\n',
        "activelearn.loop.evaluation": 'checks = {"prequential_spearman": 0.5}\n',
        "activelearn.loop.function_space": 'spearman = r["prequential_spearman"]\n',
    }
    assert _keys_built_for_strategies(sources) == ["activelearn.loop.campaign builds 'warm_start'"]


def test_the_loop_builds_no_key_for_a_strategy():
    # Strategies read what the campaign has seen from one typed History, built alike for every
    # strategy; the loop hands them no mapping whose keys only a strategy reads.
    loop = {name: path for name, path in MODULES.items() if name.startswith("activelearn.loop")}
    sources = {name: path.read_text() for name, path in loop.items()}
    assert _keys_built_for_strategies(sources) == []


def test_no_module_is_much_longer_than_600_lines():
    # A module a newcomer can read in one sitting; past ~600 lines it does more than one job.
    long = {name: n for name, path in MODULES.items() if (n := len(path.read_text().splitlines())) > 650}
    assert long == {}


# What holds a model in the generic layers, by the names the code gives it (a name or an attribute:
# `model`, `self.model`, `cfg.model`, `net`, a gate's `probe`, a residual's `base`).
_MODEL_NAMES = {"model", "net", "probe", "base", "residual", "surrogate"}


def _holds_a_model(node: ast.AST) -> bool:
    """Whether an expression names a model or a model's config: any link of `a.b.c` is a model name."""
    while isinstance(node, ast.Attribute):
        if node.attr in _MODEL_NAMES:
            return True
        node = node.value
    return isinstance(node, ast.Name) and node.id in _MODEL_NAMES


def _model_kind_checks(tree: ast.AST) -> Iterator[tuple[int, str]]:
    """(line, what) for every question about a model's kind: a comparison of its (or its config's)
    `kind`, `isinstance` of a model, `hasattr` on one, or `getattr(model, "name", default)`. Reading a
    model's `config` through `getattr(model, "config", None)` asks whether there is a model at all."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            for side in (node.left, *node.comparators):
                if isinstance(side, ast.Attribute) and side.attr == "kind" and _holds_a_model(side.value):
                    yield node.lineno, f"compares {ast.unparse(side)}"
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.args:
            probe, subject = node.func.id, node.args[0]
            if probe in ("hasattr", "isinstance") and _holds_a_model(subject):
                yield node.lineno, ast.unparse(node)
            elif probe == "getattr" and len(node.args) == 3 and _holds_a_model(subject):
                name = node.args[1]
                if not (isinstance(name, ast.Constant) and name.value == "config"):
                    yield node.lineno, ast.unparse(node)


def test_the_scan_sees_a_question_about_the_model_kind():
    before = """
def f(self, model, net, cfg, samples):
    if self.cfg.model.kind == "physics": pass
    if "physics" != cfg.model.kind: pass
    if hasattr(model, "correction_weight"): pass
    if hasattr(net, "physical_parameters"): pass
    runs = getattr(model, "open_loop_free_runs", None)
    if isinstance(self.model, PhysicsModel): pass
    block = getattr(model, "rollout_block", 16)
    arm = getattr(getattr(model, "config", None), "pose_lever_arm", 0.0)  # a None guard: allowed
    if cfg.oracle.kind == "twin" or samples.kind == "skidpad": pass  # not a model: allowed
"""
    assert [line for line, _ in _model_kind_checks(ast.parse(before))] == [3, 4, 5, 6, 7, 8, 9]


def test_only_the_models_know_their_kind():
    # Every kind is trained, fitted and recorded through one interface (`Model`'s hooks: identify,
    # gates_correction, round_metrics, physical_parameters, identifies_on_logs): outside the models
    # (and the config, which validates a kind's settings) nothing asks which kind a model is.
    bad = []
    for name, path in MODULES.items():
        inside = name.startswith(("activelearn.numerics.models", "activelearn.config"))
        if not name.startswith("activelearn") or inside:
            continue
        bad += [f"{name}:{line} {what}" for line, what in _model_kind_checks(ast.parse(path.read_text()))]
    assert bad == []


@pytest.mark.parametrize(
    ("library", "home"),
    [("mlflow", "activelearn.studies.tracking"), ("optuna", "activelearn.studies.tuning")],
)
def test_one_module_talks_to_each_service(library, home):
    importers = {
        name
        for name, path in MODULES.items()
        for target, _ in _imports(name, path)
        if target == library or target.startswith(library + ".")
    }
    assert importers, f"nothing imports {library}: the rule checks nothing"
    assert {n for n in importers if not (n == home or n.startswith(home + "."))} == set()
