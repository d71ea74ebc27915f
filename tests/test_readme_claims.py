"""Every README command and figure is checked (issue 48): a figure by docs/benchmarks.md,
a command by a test that runs it.

* Figures: every time, speed, memory, factor or percentage README.md states (the
  tokens :func:`figures` finds) is listed verbatim, in bold, in docs/benchmarks.md's
  section "Figures quoted in the README", whose every entry gives a dated
  measurement with its command or names an existing test; an entry whose figure
  has left the README fails too.
* Commands: every command of the README (its bash blocks and the inline ones that
  start with amfe, mpirun, bash, source, apt-get or python) is in :data:`COMMANDS`,
  with the tests that run it: their text holds its subcommand and every --option it
  names. The README's own blocks run here as written (:func:`test_the_using_it_block_
  runs_as_written`, :func:`test_the_python_block_runs_as_written`).
"""
import json
import os
import re
import subprocess
import sys

import pytest
from helpers import MPI_ENV, ROOT, run_cli

README = os.path.join(ROOT, "README.md")
BENCH = os.path.join(ROOT, "docs", "benchmarks.md")
SECTION = "## Figures quoted in the README"

_D = r"\d(?:[\d.,]*\d)?"
_NUM = rf"{_D}(?:\s*(?:-|/)\s*{_D})*"
#: a figure: a number (or range, or a / b / c) with a unit of time, memory, size of a
#: problem, a percentage or a factor; or a time in words ("under a millisecond")
FIGURE = re.compile(
    rf"(?<![\w.]){_NUM}\s*(?:%|x(?!\s*\d)(?=[\s,.;)])|(?:ms|s|min|minutes?|seconds?|hours?|GB"
    rf"|MB|GiB|M DOFs)(?![\w]))"
    r"|\b(?:about|under|within|in under) an? (?:minute|millisecond|second|hour)\b")

#: command (as the README has it, whitespace collapsed) -> tests that run it
COMMANDS = {
    "bash run/main.sh": ["tests/test_golden.py"],
    "bash run/test.sh": [".ci/run"],
    "source run/env.sh": ["tests/test_readme_claims.py"],
    ".venv/bin/amfe pack -o bed.h5 --size 0.7 0.7 0.25 --seed 4 --track-width 0.1 "
    "--hatch-spacing 0.12 --angle 30 --layer-rotation 67": ["tests/test_readme_claims.py"],
    "mpirun -n 2 .venv/bin/amfe homogenize bed.h5 -o result.json --vtu vtu/ -ksp_monitor "
    "-log_view": ["tests/test_readme_claims.py"],
    "amfe homogenize --bc all": ["tests/test_bounds.py"],
    "amfe pack --periodic": ["tests/test_periodic.py"],
    "amfe homogenize BED.h5 [-o RESULT.json|-] [--vtu DIR] [--solver auto|gamg|cholesky] "
    "[--rtol R] [--cap-a-star A] [--bc kubc|subc|periodic|mixed|all] [--E PA --nu NU --psi "
    "PSI] [--accept-unconverged] [--max-memory SIZE] [--diagnose] [--quiet] [--box LX LY LZ] "
    "[--model frame|voxel] [--voxel-size H] [--voxel-operator assembled|matrix-free] "
    "[--springs paper|continuum]": [
        "tests/test_golden.py", "tests/test_continuum_springs.py", "tests/test_bounds.py",
        "tests/test_reliability_solve.py",
        "tests/test_voxel_free.py", "tests/test_hard_cases.py", "tests/test_solver_faults45.py",
        "tests/test_material_rtol_origin_faults.py", "tests/test_volume_box.py",
        "tests/test_progress_lines.py"],
    "amfe view RESULT_DIR [-o DIR] [--case xx] [--color axial_force] "
    "[--backend auto|paraview|matplotlib] [--size WxH] [--state]": ["tests/test_view.py"],
    "apt-get install -y paraview python3-paraview xvfb": ["tests/test_view.py",
                                                          "docs/viewing.md"],
    "amfe pack": ["tests/test_pack_cli.py"],
    "amfe homogenize": ["tests/test_golden.py"],
    "amfe predict": ["tests/test_predict_batch.py"],
    "mpirun -n 2 .venv/bin/amfe dataset -o data.h5 --count 2000 --scale small": [
        "tests/test_dataset.py", "tests/test_boxscale.py"],
    "amfe pack --scale small --seed S": ["tests/test_dataset.py"],
    "amfe dataset --from-labels labels/small_seed3_labels_*.h5 -o data.h5": [
        "tests/test_labels.py"],
    "amfe train data.h5 --arch custom|lenet5|alexnet|vgg|multiscale -o model.pt "
    "[--inputs fill,bonds] [--width W --convs K] [--device auto|cpu|cuda]": [
        "tests/test_training.py", "tests/test_readme_claims.py"],
    "amfe predict bed.h5 [--model model.pt] [--check] [--fallback]": [
        "tests/test_training.py", "tests/test_cli_faults.py"],
    "amfe train --init": ["tests/test_stiffness_predict.py"],
    "amfe predict BED --stiffness": ["tests/test_predict_batch.py"],
    "amfe predict BED --springs continuum": ["tests/test_continuum_surrogate.py"],
    "amfe predict -o": ["tests/test_predict_batch.py"],
    "python -m amfe": ["tests/test_layout.py"],
    "source run/env.sh && .venv/bin/python -m run.report.report": [
        "tests/test_report.py", "tests/test_readme_claims.py"],
}
_COMMAND_START = re.compile(r"(bash |source |mpirun |\.venv/bin/|amfe [a-z]|apt-get |python )")


def figures(text):
    """The README figures of ``text``: [str], whitespace collapsed, in order."""
    body = re.sub(r"```.*?```", "", text, flags=re.S)        # no figures in code blocks
    body = re.sub(r"\s+", " ", body)
    return [re.sub(r"\s+", " ", m.group()) for m in FIGURE.finditer(body)]


def commands(text):
    """The README commands of ``text``: the lines of its bash blocks (continuations joined,
    comments dropped) and the inline ones, whitespace collapsed."""
    out = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line:
                out.append(re.sub(r"\s+", " ", line))
    body = re.sub(r"\s+", " ", re.sub(r"```.*?```", "", text, flags=re.S))
    for m in re.finditer(r"`([^`]+)`", body):
        if _COMMAND_START.match(m.group(1)) and m.group(1) not in ("mpirun -n N",):
            out.append(m.group(1).strip())
    return list(dict.fromkeys(out))


def entries(bench):
    """[(figures, entry text)] of the benchmarks' README section (a figure: a bold span)."""
    start = bench.index(SECTION)
    end = bench.find("\n## ", start + len(SECTION))
    section = bench[start:end if end > 0 else None]
    out = []
    for item in re.split(r"\n- ", section)[1:]:
        item = re.sub(r"\s+", " ", item)
        out.append((re.findall(r"\*\*(.+?)\*\*", item), item))
    return out


def problems(readme, bench, root=ROOT):
    """[str]: what the README states that neither docs/benchmarks.md nor a test checks."""
    found, listed, out = figures(readme), entries(bench), []
    every = {fig for figs, _ in listed for fig in figs}
    for fig in dict.fromkeys(found):
        if fig not in every:
            out.append(f"README figure {fig!r} is not in docs/benchmarks.md, {SECTION[3:]!r}")
    body = re.sub(r"\s+", " ", readme)
    for figs, item in listed:
        fig = ", ".join(figs)
        for one in figs:
            if one not in body:
                out.append(f"docs/benchmarks.md lists {one!r}, which README.md no longer "
                           "states")
        tests = re.findall(r"(tests/test_\w+\.py)::(\w+)", item)
        dated = re.search(r"20\d\d-\d\d-\d\d", item) and re.search(r"`[^`]+`", item)
        if not tests and not dated:
            out.append(f"{fig!r}: its entry gives neither a dated measurement with its command "
                       "nor a test")
        for path, name in tests:
            full = os.path.join(root, path)
            if not os.path.exists(full) or f"def {name}(" not in open(full).read():
                out.append(f"{fig!r}: {path}::{name} does not exist")
    for cmd in commands(readme):
        if cmd not in COMMANDS:
            out.append(f"README command {cmd!r} is run by no test listed in COMMANDS")
            continue
        text = "".join(open(os.path.join(root, p)).read() for p in COMMANDS[cmd])
        # its long options, PETSc's (-ksp_monitor) and the scripts it runs
        words = re.findall(r"(?<![\w-])(?:--[a-z][\w-]*|-[a-z]+_[\w]+)|run/\w+\.sh", cmd)
        sub = re.match(r"(?:.*?amfe )([a-z]+)", cmd)
        for word in words + ([sub.group(1)] if sub else []):
            if word.startswith("amfe "):
                continue
            if word not in text and word.lstrip("-").replace("-", "_") not in text:
                out.append(f"README command {cmd!r}: {word!r} appears in none of "
                           f"{COMMANDS[cmd]}")
    return out


def test_every_readme_figure_and_command_is_checked():
    with open(README) as f, open(BENCH) as g:
        found = problems(f.read(), g.read())
    assert not found, "\n".join(found)


def test_the_check_fails_on_an_unlisted_figure_a_stale_entry_and_an_unrun_command():
    with open(README) as f, open(BENCH) as g:
        readme, bench = f.read(), g.read()
    assert figures("takes 3-4 s, 2.5x faster, 12 % off, about a minute; a 3 x 3 mm bed") == [
        "3-4 s", "2.5x", "12 %", "about a minute"]
    more = readme + "\nIt solves any bed in 0.2 s.\n\n`amfe frobnicate --hard`\n"
    found = problems(more, bench)
    assert any("'0.2 s'" in p for p in found) and any("frobnicate" in p for p in found)
    stale = bench.replace(SECTION, SECTION + "\n\n- **7.77 s**: 2026-12-05, `true`\n", 1)
    assert any("'7.77 s'" in p and "no longer" in p for p in problems(readme, stale))
    undated = bench.replace(SECTION, SECTION + "\n\n- **about a minute**: trust me\n", 1)
    assert any("neither" in p for p in problems(readme, undated))


def _env():
    return dict(MPI_ENV, PATH=os.path.dirname(sys.executable) + os.pathsep + MPI_ENV["PATH"])


def test_the_using_it_block_runs_as_written(tmp_path):
    """The README's "Using it" block, with .venv/bin/ pointing at this interpreter's amfe; its
    result equals amfe.homogenize of the same bed in this process."""
    import amfe

    with open(README) as f:
        block = [b for b in re.findall(r"```bash\n(.*?)```", f.read(), flags=re.S)
                 if ".venv/bin/amfe pack" in b][0]
    venv = tmp_path / ".venv" / "bin"
    venv.mkdir(parents=True)
    (venv / "amfe").symlink_to(os.path.join(os.path.dirname(sys.executable), "amfe"))
    script = block.replace("source run/env.sh", f"source {ROOT}/run/env.sh")
    proc = subprocess.run(["bash", "-euo", "pipefail", "-c", script], cwd=tmp_path, env=_env(),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "KSP" in proc.stdout or "Residual norm" in proc.stdout      # -ksp_monitor reached
    assert "PETSc Performance Summary" in proc.stdout                 # -log_view reached
    with open(tmp_path / "result.json") as f:
        got = json.load(f)["properties"]
    assert (tmp_path / "vtu" / "cases.pvd").is_file()
    ref = amfe.homogenize(str(tmp_path / "bed.h5"))
    for name in ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy"):
        assert got[name] == pytest.approx(ref.properties[name], rel=1e-6), name


def test_the_python_block_runs_as_written(tmp_path):
    with open(README) as f:
        code = re.findall(r"```python\n(.*?)```", f.read(), flags=re.S)[0]
    env = _env()
    pack = subprocess.run([sys.executable, "-m", "amfe.cli", "pack", "-o", "small_bed.h5",
                           "--scale", "small", "--seed", "1"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert pack.returncode == 0, pack.stderr
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    for name in ("result.json", "p.json", "vtu/cases.pvd"):
        assert (tmp_path / name).is_file(), name
    with open(tmp_path / "p.json") as f:
        p = json.load(f)
    ex = p["beds"][0]["properties"]["Ex"] if "beds" in p else p["properties"]["Ex"]
    assert 1e9 < ex < 400e9


def test_a_wider_deeper_custom_net_trains_from_the_command_line(tmp_path):
    """`amfe train ... --width W --convs K` (README, "The CNN surrogate"): the checkpoint's
    members have the wider, deeper net's parameter count."""
    from test_training import TINY_ATTRS, write_synthetic

    from amfe.training.checkpoint import load_checkpoint
    from amfe.training.nets import build_net, count_parameters

    data = write_synthetic(tmp_path / "tiny.h5", n=24, shape=(1, 5, 5), attrs=TINY_ATTRS)
    model = tmp_path / "wide.pt"
    proc = run_cli(["train", str(data), "--arch", "custom", "-o", str(model), "--width", "2",
                    "--convs", "2", "--epochs", "1", "--members", "1", "--batch-size", "8",
                    "--threads", "1"])
    assert proc.returncode == 0, proc.stderr
    ck = load_checkpoint(str(model))
    state = ck["members"][0] if "members" in ck else ck["state_dicts"][0]
    n = sum(v.numel() for v in state.values() if hasattr(v, "numel"))
    assert n == count_parameters(build_net("custom", (1, 5, 5), {"width": 2.0, "convs": 2}))
    assert n != count_parameters(build_net("custom", (1, 5, 5)))
