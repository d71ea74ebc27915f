"""How data cross the layers, checked from the source (issue 29).

- No function takes more than 8 parameters (self and cls excluded): values travel
  as a checked Bed and a SolveOptions, not as long lists of arrays and flags. The
  user-facing keyword options of amfe.homogenize, amfe.predict, amfe.sweep and
  amfe.generate_bed are the exception.
- solvers/ neither prints nor writes to stdout or stderr: progress and warnings
  leave it through ``logging`` (amfe.io.console prints them for the face).
- At most 3 function bodies in amfe/, solvers/ and training/ are longer than 80
  lines, counted without their docstrings.
"""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_PARAMETERS = 8
MAX_BODY_LINES = 80
MAX_LONG_BODIES = 3
USER_FACING = {("amfe/api.py", "homogenize"), ("amfe/model/bed.py", "generate_bed"),
               ("amfe/study/__init__.py", "sweep"), ("amfe/predicting.py", "predict")}


def functions():
    """(relative path, function node) of every function in amfe/, solvers/ and training/."""
    for top in ("amfe", "solvers", "training"):
        for path in sorted((ROOT / top).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    yield rel, node


def parameters(node):
    a = node.args
    names = [p.arg for p in a.posonlyargs + a.args + a.kwonlyargs if p.arg not in ("self", "cls")]
    return len(names) + (a.vararg is not None) + (a.kwarg is not None)


def body_lines(node):
    """Lines from the first statement after the docstring to the last one."""
    body = node.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str):
        body = body[1:]
    return body[-1].end_lineno - body[0].lineno + 1 if body else 0


def test_no_function_takes_more_than_8_parameters():
    bad = [f"{rel}:{node.lineno} {node.name} ({parameters(node)})"
           for rel, node in functions()
           if parameters(node) > MAX_PARAMETERS and (rel, node.name) not in USER_FACING]
    assert not bad, "functions with more than 8 parameters: " + ", ".join(bad)


def test_at_most_3_function_bodies_over_80_lines():
    long = [f"{rel}:{node.lineno} {node.name} ({body_lines(node)})"
            for rel, node in functions()
            if body_lines(node) > MAX_BODY_LINES]
    assert len(long) <= MAX_LONG_BODIES, "function bodies over 80 lines: " + ", ".join(long)


def test_the_solver_layer_neither_prints_nor_writes_to_the_terminal():
    bad = []
    for path in sorted((ROOT / "solvers").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            name = None
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                name = node.func.id if node.func.id == "print" else None
            elif isinstance(node, ast.Attribute) and node.attr in ("stdout", "stderr",
                                                                   "__stdout__", "__stderr__"):
                name = f"sys.{node.attr}"
            if name:
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno} {name}")
    assert not bad, "the solver layer prints: " + ", ".join(bad)


def test_the_checks_can_fail(tmp_path):
    """The counters see what they must: a long, wide, printing function."""
    source = "def f(a, b, c, d, e, f, g, h, i):\n    '''doc'''\n" + "    print(1)\n" * 81
    node = ast.parse(source).body[0]
    assert parameters(node) == 9 and body_lines(node) == 81
    method = ast.parse("class A:\n    def m(self, *a, **k): pass\n").body[0].body[0]
    assert parameters(method) == 2


def module_imports():
    """{module: set of amfe modules it imports}, imports inside functions included, for every
    module of amfe/, solvers/ and training/ (a package's __init__ is the package's name)."""
    names = {}
    for top, package in (("amfe", "amfe"), ("solvers", "amfe.solvers"),
                         ("training", "amfe.training")):
        for path in sorted((ROOT / top).rglob("*.py")):
            rel = path.relative_to(ROOT / top).with_suffix("")
            names[".".join([package, *[p for p in rel.parts if p != "__init__"]])] = path
    graph = {}
    for module, path in names.items():
        pkg = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
        out = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(pkg.split(".")[:len(pkg.split(".")) - node.level + 1]
                                    + ([node.module] if node.module else []))
                targets = [f"{base}.{a.name}" for a in node.names] + [base]
            else:
                continue
            for t in targets:   # the longest known module the name lies in
                while t and t not in names:
                    t = t.rpartition(".")[0]
                if t and t != module:
                    out.add(t)
        graph[module] = out
    return graph


def cycles(graph):
    """The strongly connected components of more than one module (Tarjan), sorted."""
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
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
                found.append(sorted(comp))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def test_no_import_circles():
    """No two modules import each other, directly or round a longer circle, not even inside a
    function (issue 44): a shared part lives in a module both import."""
    assert cycles(module_imports()) == []


def test_the_circle_check_sees_a_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert cycles(graph) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []
