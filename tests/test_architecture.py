"""The codebase's shape, checked: the layers and their imports, module and function sizes.

Layers, lowest first: ``core`` (never imports bpy) < ``farm`` < ``blender`` < ``cli``; a module never
imports from a higher layer, not even inside a function, and the modules import one another without
circles (module-level imports; a function-level import is how a lower module defers a heavy one).
"""

import ast
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PKG = os.path.join(ROOT, "addon")
LAYERS = {"core": 0, "farm": 1, "blender": 2, "cli": 3}
MAX_MODULE_LINES = 800
MAX_FUNCTION_LINES = 120
NUMBA_DECORATORS = ("njit", "jit", "intrinsic", "generated_jit", "vectorize", "guvectorize")


def _modules():
    for dirpath, dirnames, files in os.walk(PKG):
        dirnames[:] = [d for d in dirnames if d != "__pycache__"]
        for f in sorted(files):
            if f.endswith(".py"):
                path = os.path.join(dirpath, f)
                rel = os.path.relpath(path, PKG)[:-3].replace(os.sep, ".")
                name = rel[: -len(".__init__")] if rel.endswith("__init__") else rel
                yield (name if name != "__init__" else ""), path


def _resolve(module, node, is_package):
    """The addon-relative module names one ImportFrom/Import statement refers to."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name.split(".")[0] == "bpy"]
    if node.level == 0:
        return [node.module] if node.module and node.module.split(".")[0] == "bpy" else []
    parts = module.split(".") if module else []
    base = parts if is_package else parts[:-1]
    base = base[: len(base) - (node.level - 1)]
    target = ".".join(base + ([node.module] if node.module else []))
    out = []
    for a in node.names:  # `from . import x`: x may be a module
        cand = f"{target}.{a.name}" if target else a.name
        out.append(cand if os.path.exists(_path_of(cand)) else target)
    return out


def _path_of(name):
    p = os.path.join(PKG, *name.split("."))
    return p + ".py" if os.path.isfile(p + ".py") else os.path.join(p, "__init__.py")


def _imports():
    graph, anywhere = {}, {}
    for name, path in _modules():
        tree = ast.parse(open(path, encoding="utf-8").read())
        is_package = path.endswith("__init__.py")
        top = {
            t for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom)) for t in _resolve(name, n, is_package)
        }
        every = {
            t
            for n in ast.walk(tree)
            if isinstance(n, (ast.Import, ast.ImportFrom))
            for t in _resolve(name, n, is_package)
        }
        graph[name], anywhere[name] = top, every
    return graph, anywhere


def _numba_kernel(node):
    """A function under a numba decorator (``@njit(...)``, ``@numba.jit``, our ``@_intrinsic``)."""
    names = {ast.unparse(d).split("(")[0].split(".")[-1].lstrip("_") for d in node.decorator_list}
    return bool(names & set(NUMBA_DECORATORS))


def _layer(name):
    return LAYERS.get(name.split(".")[0]) if name else None


def test_no_import_from_a_higher_layer():
    _, anywhere = _imports()
    bad = []
    for mod, targets in anywhere.items():
        lm = _layer(mod)
        for t in targets:
            if t.split(".")[0] == "bpy":
                if mod.startswith("core"):
                    bad.append(f"{mod} imports bpy")
                continue
            lt = _layer(t)
            if lm is not None and lt is not None and lt > lm:
                bad.append(f"{mod} -> {t}")
    assert not bad, bad


def test_no_import_circles():
    graph, _ = _imports()
    graph = {m: {t for t in ts if t in graph and t != m} for m, ts in graph.items()}
    # a package's __init__ importing its own submodules is not a circle back into it
    seen, stack, cycles = {}, [], []

    def visit(m):
        seen[m] = 1
        stack.append(m)
        for t in graph[m]:
            if seen.get(t) == 1 and not (m == "" or t == "" or t.startswith(m + ".") or m.startswith(t + ".")):
                cycles.append(stack[stack.index(t) :] + [t])
            elif t not in seen:
                visit(t)
        stack.pop()
        seen[m] = 2

    for m in sorted(graph):
        if m not in seen:
            visit(m)
    assert not cycles, cycles


def test_module_and_function_sizes():
    big_modules, big_functions = [], []
    for name, path in _modules():
        text = open(path, encoding="utf-8").read()
        n = text.count("\n")
        if n > MAX_MODULE_LINES:
            big_modules.append(f"{name}: {n} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES and not _numba_kernel(node):
                    big_functions.append(f"{name}.{node.name}: {length} lines")
    assert not big_modules and not big_functions, big_modules + big_functions


def test_public_core_functions_have_type_hints():
    """Every public function of the core (module level and public methods of public classes; numba
    kernels excepted) annotates each parameter and its return."""
    missing = []
    for name, path in _modules():
        if not name.startswith("core"):
            continue

        def visit(body, public=True, name=name):
            for node in body:
                if isinstance(node, ast.ClassDef):
                    visit(node.body, public and not node.name.startswith("_"), name)
                elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    if node.name.startswith("_") or not public:
                        continue
                    if _numba_kernel(node):
                        continue
                    a = node.args
                    args = [x for x in a.posonlyargs + a.args + a.kwonlyargs if x.arg not in ("self", "cls")]
                    args += [x for x in (a.vararg, a.kwarg) if x is not None]
                    if node.returns is None or any(x.annotation is None for x in args):
                        missing.append(f"{name}.{node.name}")

        visit(ast.parse(open(path, encoding="utf-8").read()).body)
    assert not missing, missing


def _private_uses():
    """(module, name) for every private name (``_x``) one module of the add-on takes from another: imported
    by name, or read as an attribute of an imported module."""
    out = []
    for name, path in _modules():
        tree = ast.parse(open(path, encoding="utf-8").read())
        is_package = path.endswith("__init__.py")
        modules = set()  # local names bound to one of the add-on's modules
        for n in ast.walk(tree):
            if not isinstance(n, ast.ImportFrom) or n.level == 0:
                continue
            parts = name.split(".") if name else []
            base = parts if is_package else parts[:-1]
            base = base[: len(base) - (n.level - 1)]
            target = ".".join(base + ([n.module] if n.module else []))
            for a in n.names:
                sub = f"{target}.{a.name}" if target else a.name
                if os.path.exists(_path_of(sub)) and (sub.endswith(a.name)):
                    modules.add(a.asname or a.name)
                elif a.name.startswith("_") and not a.name.startswith("__"):
                    out.append(f"{name} imports {target}.{a.name}")
        for n in ast.walk(tree):
            if (
                isinstance(n, ast.Attribute)
                and isinstance(n.value, ast.Name)
                and n.value.id in modules
                and n.attr.startswith("_")
                and not n.attr.startswith("__")
            ):
                out.append(f"{name} reads {n.value.id}.{n.attr}")
    return sorted(set(out))


def test_no_private_name_is_used_across_modules():
    assert not _private_uses(), _private_uses()


def test_the_private_name_check_sees_an_import_and_an_attribute(tmp_path, monkeypatch):
    pkg = tmp_path / "addon" / "core"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def _hidden():\n    return 1\n")
    (pkg / "b.py").write_text("from .a import _hidden\n")
    (pkg / "c.py").write_text("from . import a\n\nx = a._hidden()\n")
    monkeypatch.setattr(sys.modules[__name__], "PKG", str(tmp_path / "addon"))
    assert _private_uses() == ["core.b imports core.a._hidden", "core.c reads a._hidden"]
