"""Count the shape of ``secure3d/`` (issue 22): long functions, long modules, import cycles, and
checks of a vehicle's name or type outside ``secure3d/dynamics/``.

Usage: ``python benchmarks/code_shape.py [--verbose]``. Reads the source with :mod:`ast` only
(imports nothing from the package), so it runs in a second.

- A function is over the limit when its ``def`` line to its last line spans more than
  ``--function-lines`` (80) lines; functions decorated with a numba ``njit``/``jit`` are excepted.
- A module is over the limit when it has more than ``--module-lines`` (600) lines.
- Import cycles are strongly connected components of the graph of ``secure3d`` modules, counting
  every import, including those inside functions (the ones that hide a cycle from import time).
  Importing a package counts as importing its ``__init__``.
- Vehicle checks: ``isinstance(..., <model class>)``, comparisons of ``.name`` with a vehicle name,
  any string literal naming a vehicle, and ``getattr`` on vehicle-specific limit names.
"""

from __future__ import annotations

import argparse
import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "secure3d"

#: Names of the vehicle models and their classes (a check of any of these outside dynamics/ counts).
VEHICLE_NAMES = {"point_mass", "quadrotor", "diff_drive"}
MODEL_CLASSES = {
    "PointMass",
    "Quadrotor",
    "DiffDrive",
    "PointMassModel",
    "QuadrotorModel",
    "DiffDriveModel",
}
#: Limit fields that only some vehicles have (reading them by name is a check of the vehicle).
VEHICLE_LIMITS = {
    "max_yaw_rate",
    "max_ang_speed",
    "max_tilt",
    "max_thrust",
    "max_accel",
    "max_speed",
    "max_omega",
    "max_vz",
}


#: The one-way layering (README): a module may import its own layer and the ones before it.
LAYERS = ("geometry", "mapping", "dynamics", "reactive", "world", "planning", "simulation", "viz")


def layer(mod: str) -> int:
    """0 for package-wide helpers (errors, outputs, ...), 1.. for LAYERS, 99 for the edges that
    consume everything (the CLI, ``secure3d.warm``, the ``secure3d paper`` application, and
    ``secure3d.session``: a flight with its recording and figure)."""
    parts = mod.split(".")
    if len(parts) > 1 and parts[1] in LAYERS:
        return LAYERS.index(parts[1]) + 1
    edges = ("secure3d", "secure3d.__main__", "secure3d.warm", "secure3d.paper", "secure3d.session")
    if mod in edges or mod.startswith("secure3d.cli"):
        return 99
    return 0


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _is_numba(fn: ast.AST) -> bool:
    for dec in getattr(fn, "decorator_list", []):
        text = ast.unparse(dec)
        if "njit" in text or "jit(" in text or text.endswith("jit") or "vectorize" in text:
            return True
    return False


def long_functions(tree: ast.Module, limit: int) -> list[tuple[str, int]]:
    found = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                n = child.end_lineno - child.lineno + 1
                if n > limit and not _is_numba(child):
                    found.append((name, n))
                visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(tree, "")
    return found


def _import_nodes(tree: ast.Module):
    """Yield ``(node, deferred)`` for every import, skipping ``if TYPE_CHECKING:`` blocks;
    *deferred* is true for an import inside a function (run on call, not on import)."""

    def visit(node: ast.AST, deferred: bool):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                for sub in child.orelse:
                    yield from visit(sub, deferred)
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                yield child, deferred
            yield from visit(
                child, deferred or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            )

    yield from visit(tree, False)


def imports_of(tree: ast.Module, mod: str, is_pkg: bool, known: set[str]) -> dict[str, bool]:
    """The package modules *mod* imports, each mapped to True when every such import is deferred."""
    out: dict[str, bool] = {}
    pkg = mod if is_pkg else mod.rpartition(".")[0]
    for node, deferred in _import_nodes(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[: len(base) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            # ``from pkg import sub`` imports the submodule; ``from pkg import name`` the package
            targets = [
                f"{stem}.{a.name}" if f"{stem}.{a.name}" in known else stem for a in node.names
            ]
        else:
            continue
        for t in targets:
            # the longest known module that prefixes the target
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != mod:
                out[t] = out.get(t, True) and deferred
    return out


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, comps = {}, {}, [], set(), []
    counter = [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return comps


def vehicle_checks(tree: ast.Module) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            if node.func.id == "isinstance" and len(node.args) == 2:
                names = {
                    n.id if isinstance(n, ast.Name) else getattr(n, "attr", "")
                    for n in ast.walk(node.args[1])
                }
                if names & MODEL_CLASSES:
                    found.append((node.lineno, ast.unparse(node)))
            if node.func.id in ("getattr", "hasattr") and len(node.args) >= 2:
                arg = node.args[1]
                if isinstance(arg, ast.Constant) and arg.value in VEHICLE_LIMITS:
                    found.append((node.lineno, ast.unparse(node)[:100]))
        elif isinstance(node, ast.Constant) and node.value in VEHICLE_NAMES:
            found.append((node.lineno, repr(node.value)))
    return sorted(set(found))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--function-lines", type=int, default=80)
    parser.add_argument("--module-lines", type=int, default=600)
    parser.add_argument("--verbose", "-v", action="store_true")
    args = parser.parse_args(argv)

    files = sorted(PACKAGE.rglob("*.py"))
    trees = {module_name(f): (f, ast.parse(f.read_text(), filename=str(f))) for f in files}
    known = set(trees)

    funcs, mods, graph, checks = [], [], defaultdict(dict), []
    n_functions = 0
    for mod, (path, tree) in trees.items():
        rel = path.relative_to(ROOT)
        n_functions += sum(
            isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) for n in ast.walk(tree)
        )
        funcs += [(f"{rel}:{name}", n) for name, n in long_functions(tree, args.function_lines)]
        lines = len(path.read_text().splitlines())
        if lines > args.module_lines:
            mods.append((str(rel), lines))
        graph[mod].update(imports_of(tree, mod, path.name == "__init__.py", known))
        if "dynamics" not in rel.parts:
            checks += [(f"{rel}:{line}", text) for line, text in vehicle_checks(tree)]
    # A package's __init__ importing its own submodules is not a design cycle: drop the edges from a
    # package to the modules under it (re-exports), keep everything else.
    for mod in list(graph):
        graph[mod] = {t: d for t, d in graph[mod].items() if not t.startswith(mod + ".")}
    found_cycles = cycles(graph)
    upward = sorted(
        (a, b) for a in graph for b in graph[a] if layer(b) > layer(a) and layer(b) != 99
    )

    print(f"secure3d: {len(files)} modules, {n_functions} functions")
    print(f"functions over {args.function_lines} lines: {len(funcs)}")
    print(f"modules over {args.module_lines} lines: {len(mods)}")
    in_cycles = sum(len(c) for c in found_cycles)
    print(f"import cycles: {len(found_cycles)} ({in_cycles} modules)")
    print(f"imports against the layering: {len(upward)}")
    print(f"vehicle checks outside dynamics/: {len(checks)}")
    if args.verbose:
        for name, n in sorted(funcs, key=lambda x: -x[1]):
            print(f"  fn   {n:5d}  {name}")
        for name, n in sorted(mods, key=lambda x: -x[1]):
            print(f"  mod  {n:5d}  {name}")
        for comp in found_cycles:
            print(f"  cycle  {len(comp)} modules: {' '.join(comp)}")
            inside = set(comp)
            for a in comp:
                for b, deferred in sorted(graph[a].items()):
                    if b in inside and deferred:
                        print(f"    deferred import  {a} -> {b}")
        for a, b in upward:
            print(f"  upward  {a} -> {b}")
        for where, text in checks:
            print(f"  vehicle  {where}  {text}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
