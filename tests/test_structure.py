"""How data cross the layers, checked from the source (issue 29).

- No function takes more than 8 parameters (self and cls excluded): values travel
  as a checked Bed and a SolveOptions, not as long lists of arrays and flags. The
  user-facing keyword options of amfe.homogenize and amfe.generate_bed are the
  exception.
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
               ("amfe/study/__init__.py", "sweep")}


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
