"""The package's shape, checked from the source: one top-level package, layers, file sizes.

Layers, bottom to top (README, Layout): core (errors, vocab, version, signals), model,
io, solvers, dataset, training, face (amfe/__init__, api, predicting, cli). No module
imports from a layer above its own, indented (lazy) imports included.
"""
import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ["core", "model", "io", "solvers", "dataset", "training", "face"]
# Heavy dependencies each layer may not import at all.
FORBIDDEN = {"core": {"petsc4py", "mpi4py", "torch", "h5py"},
             "model": {"petsc4py", "mpi4py", "torch"},
             "io": {"petsc4py", "torch"},
             "solvers": {"torch"},
             "dataset": {"torch"}}


def source_files():
    for top, package in (("amfe", "amfe"), ("solvers", "amfe.solvers"),
                         ("training", "amfe.training")):
        for path in sorted((ROOT / top).rglob("*.py")):
            rel = path.relative_to(ROOT / top).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            yield path, ".".join([package, *parts])


def layer_of(module):
    parts = module.split(".")
    if parts[0] != "amfe":
        return None
    if len(parts) == 1 or parts[1] in ("api", "cli", "__main__", "study", "predicting"):
        return "face"
    if parts[1] in ("errors", "vocab", "version", "signals"):
        return "core"
    if parts[1] in ("model", "io", "solvers", "dataset", "training"):
        return parts[1]
    if parts[1] == "viz":  # pictures of results: reads files via io, no PETSc or torch
        return "dataset"
    raise AssertionError(f"module {module} belongs to no layer: add it to the layout")


def imports_of(path, module):
    tree = ast.parse(path.read_text())
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module
            yield node.lineno, name
            for alias in node.names:  # `from amfe import model` imports amfe.model
                yield node.lineno, f"{name}.{alias.name}"


def test_no_import_runs_upward():
    bad = []
    for path, module in source_files():
        mine = LAYERS.index(layer_of(module))
        for line, name in imports_of(path, module):
            top = name.split(".")[0]
            if top in ("solvers", "training"):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports top-level {name}")
                continue
            if top in FORBIDDEN.get(layer_of(module), ()):
                bad.append(f"{path.relative_to(ROOT)}:{line} ({layer_of(module)}) imports {name}")
            if top != "amfe":
                continue
            try:
                theirs = layer_of(name)
            except AssertionError:
                continue  # `from amfe.x import name`: the module itself was checked
            if name == "amfe.version" or name.startswith("amfe.version."):
                continue
            if theirs and LAYERS.index(theirs) > mine:
                bad.append(f"{path.relative_to(ROOT)}:{line} ({layer_of(module)}) imports "
                           f"{name} ({theirs})")
    assert not bad, "imports that run upward:\n" + "\n".join(bad)


def test_the_data_set_code_has_one_home():
    # Data-set files, their parts and runs live in amfe/dataset/ (issue 29, item 5); io keeps
    # the general files (beds, results, ParaView, atomic writes).
    strays = [p.relative_to(ROOT).as_posix() for p, module in source_files()
              if layer_of(module) not in ("dataset", "face") and "dataset" in p.stem]
    assert not strays, "data-set modules outside amfe/dataset/: " + ", ".join(strays)
    assert (ROOT / "amfe" / "dataset" / "datafile.py").is_file()
    assert (ROOT / "amfe" / "dataset" / "parts.py").is_file()


def test_the_checker_sees_an_upward_import(tmp_path):
    # The test above must be able to fail: an upward import is caught.
    path = tmp_path / "bonds.py"
    path.write_text("def f():\n    from amfe.solvers.driver import homogenize_bed\n")
    found = [name for _, name in imports_of(path, "amfe.model.bonds")]
    assert "amfe.solvers.driver" in found
    assert (LAYERS.index(layer_of("amfe.solvers.driver"))
            > LAYERS.index(layer_of("amfe.model.bonds")))


def test_no_file_over_400_lines():
    long = [f"{p.relative_to(ROOT)}: {n}" for p, _ in source_files()
            if (n := len(p.read_text().splitlines())) > 400]
    assert not long, "files over 400 lines:\n" + "\n".join(long)


def test_code_cites_only_docs_the_repository_has():
    bad = []
    for path, _ in source_files():
        for k, line in enumerate(path.read_text().splitlines(), 1):
            if "DESIGN" in line:
                bad.append(f"{path.relative_to(ROOT)}:{k}: {line.strip()}")
    assert not bad, "cite docs/model.md, not DESIGN:\n" + "\n".join(bad)


def test_one_top_level_package_installed(tmp_path):
    # From outside the checkout only `amfe` is importable; solvers and training live under it.
    code = ("import importlib.util as u, sys\n"
            "print(u.find_spec('amfe') is not None, u.find_spec('solvers'), "
            "u.find_spec('training'))\n"
            "import amfe.solvers.ksp, amfe.training\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, env={**os.environ, "PYTHONPATH": ""})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "None", "None"]


def test_import_amfe_pulls_in_neither_petsc_nor_torch(tmp_path):
    code = ("import sys, amfe, amfe.model.bed, amfe.io.bedfile, amfe.api, amfe.model.options\n"
            "print(sorted(m for m in ('petsc4py', 'torch', 'mpi4py') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_a_command_line_loads_its_own_command_only(tmp_path):
    """`amfe sweep ...` registers the sweep's parser alone (the other commands' modules, and
    the solver's that homogenize pulls in, cost 0.1-0.2 s of every rank's start); a line
    that names no command gets the whole parser, every command in its usage."""
    code = ("import sys\n"
            "from amfe.cli import build_parser, parse\n"
            "args = parse(['sweep', '-o', 'x', '--grid', 'hatch_spacing=0.1'])\n"
            "print(args.command, sorted(m.rsplit('.', 1)[1] for m in sys.modules\n"
            "      if m.startswith('amfe.cli.') and m.rsplit('.', 1)[1] in\n"
            "      ('pack', 'homogenize', 'dataset', 'train', 'predict', 'view', 'sweep')))\n"
            "print(sorted(build_parser().subcommands))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True)
    assert out.returncode == 0, out.stderr
    first, every = out.stdout.splitlines()
    assert first == "sweep ['sweep']"
    assert every == str(sorted(["pack", "homogenize", "dataset", "train", "predict", "view",
                                "sweep"]))


@pytest.mark.parametrize("name", ["homogenize", "Result", "Fields", "read_bed", "Bed",
                                  "generate_bed", "Surrogate", "homogenize_bed", "SolveOptions",
                                  "AmfeError", "predict", "Prediction"])
def test_the_face_lists_the_api(name):
    import amfe
    assert name in dir(amfe) and name in amfe.__all__
    assert getattr(amfe, name) is not None


def test_version_and_python_m_amfe():
    import amfe
    out = subprocess.run([sys.executable, "-m", "amfe", "--version"], capture_output=True,
                         text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"amfe {amfe.__version__}"


RUN = ROOT / "run"


def run_scripts():
    """The scripts of run/'s folders (not the package markers or common.py)."""
    return sorted(p for p in RUN.glob("*/*") if p.suffix in (".py", ".sh")
                  and p.name != "__init__.py")


def test_run_is_ordered_short_and_plain():
    """run/ by purpose: no file over 400 lines, no sys.path edits, every script listed in
    run/README.md under its folder and every listed one there (issue 44)."""
    index = (RUN / "README.md").read_text()
    listed = set(re.findall(r"^## run/(\w+)/.*?(?=^## |\Z)", index, flags=re.S | re.M))
    assert listed == {"bench", "report", "train", "probes"}
    long = [f"{p.relative_to(ROOT)}: {n}" for p in RUN.rglob("*.py")
            if (n := len(p.read_text().splitlines())) > 400]
    assert not long, "run/ files over 400 lines: " + ", ".join(long)
    edits = [str(p.relative_to(ROOT)) for p in RUN.rglob("*.py")
             if "sys.path.insert" in p.read_text() and p.name != "common.py"]
    assert not edits, "sys.path edited in " + ", ".join(edits)
    sections = {m.group(1): m.group(2) for m in
                re.finditer(r"^## run/(\w+)/[^\n]*\n(.*?)(?=^## |\Z)", index, flags=re.S | re.M)}
    for p in run_scripts():
        assert f"`{p.name}`" in sections.get(p.parent.name, ""), f"{p.relative_to(ROOT)} unlisted"
    for folder, text in sections.items():
        for name in re.findall(r"^- `([\w.]+)`", text, flags=re.M):
            assert (RUN / folder / name).is_file(), f"run/README.md lists run/{folder}/{name}"


def test_every_run_path_the_docs_name_exists():
    """Every run/... file that README.md and docs/*.md name exists (after the move to folders)."""
    missing = []
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for path in set(re.findall(r"\brun/[\w/]+\.(?:py|sh)\b", doc.read_text())):
            if not (ROOT / path).is_file():
                missing.append(f"{doc.relative_to(ROOT)}: {path}")
        for module in set(re.findall(r"-m (run(?:\.\w+)+)", doc.read_text())):
            if not (ROOT / (module.replace(".", "/") + ".py")).is_file():
                missing.append(f"{doc.relative_to(ROOT)}: {module}")
    assert not missing, "named but absent: " + ", ".join(sorted(missing))


def test_no_import_circles_in_run():
    """run/'s scripts import each other without circles (issue 44), lazy imports included."""
    from test_structure import cycles
    graph = {}
    for p in RUN.rglob("*.py"):
        name = ".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        deps = set()
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("run"):
                deps |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
            elif isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name.startswith("run")}
        graph[name] = deps
    known = set(graph)
    graph = {k: {d for d in v if d in known and d != k} for k, v in graph.items()}
    assert cycles(graph) == []
