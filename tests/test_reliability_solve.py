"""Issue 18, the solve side: each test reruns a command the issue found wrong and checks the fix.

Items: 2 (convergence is a contract; unused PETSc options), 3 (materials),
5 (complex arrays), 7 (outputs checked first; -o over the input), 10 (seeds
in pack), 11 (memory estimates), 12 (extreme coordinates, attribute types),
13 (wrong messages). Commands with PETSc options run as subprocesses (the
options database is per process); the others run in-process.
"""
import json
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest
from helpers import MPI_ENV, ROOT, run_cli

import amfe
from amfe.cli import main
from amfe.errors import AmfeError
from amfe.io.bedfile import read_bed, write_bed
from amfe.model.bed import Bed, generate_bed
from amfe.model.material import resolve_material
from amfe.model.memory import direct_bytes, generation_bytes, parse_size, solve_bytes

ISSUE_SIZE = (0.15e-3, 0.15e-3, 0.08e-3)   # the issue's bed (168 particles, seed 0)


@pytest.fixture(scope="module")
def bed_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("rel") / "bed.h5"
    write_bed(path, generate_bed(size=ISSUE_SIZE, seed=0))
    return str(path)


@pytest.fixture(scope="module")
def converged(bed_file):
    return amfe.homogenize(bed_file)


def one_error_line(stderr, command="homogenize"):
    """The single 'amfe CMD: error:' line of a failed run (and no traceback)."""
    assert "Traceback" not in stderr
    lines = [ln for ln in stderr.splitlines() if ln.startswith(f"amfe {command}: error:")]
    assert len(lines) == 1, stderr
    return lines[0]


# ----------------------------------------------------------------- item 2: convergence


@pytest.mark.parametrize("options, stopped", [
    (["-ksp_atol", "1e3"], "CONVERGED_ATOL after 0 iterations"),
    (["-ksp_type", "preonly", "-pc_type", "jacobi"], "CONVERGED_ITS"),
    (["-ksp_max_it", "1"], "DIVERGED_MAX_IT"),
])
def test_solve_that_misses_the_tolerance_is_an_error(bed_file, tmp_path, options, stopped):
    # --solver gamg: the issue's runs used CG + GAMG (today's default, auto, factorises this bed)
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", bed_file, "-o", str(out), "--quiet", "--solver", "gamg",
                    *options])
    assert proc.returncode == 2
    line = one_error_line(proc.stderr)
    assert stopped in line and "--accept-unconverged" in line
    assert not out.exists()


def test_accept_unconverged_keeps_the_numbers_with_a_warning(bed_file, converged, tmp_path):
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", bed_file, "-o", str(out), "--quiet", "-ksp_atol", "1e3",
                    "--solver", "gamg", "--accept-unconverged"])
    assert proc.returncode == 0, proc.stderr
    r = json.loads(out.read_text())
    assert len(r["warnings"]) == 6 and all("CONVERGED_ATOL" in w for w in r["warnings"])
    # (KUBC on a box: the default rtol of the second-order stress, docs/model.md section 5)
    assert min(r["solver"]["residuals"]) > r["solver"]["residual_limit"] == 10 * 1e-5
    # the issue's numbers: 0 iterations, Ex 8 % high from the affine start; the second-order
    # stress takes that start's residual into account and brings it to 3.3 % high
    assert r["solver"]["iterations"] == [0] * 6
    assert r["properties"]["Ex"] / converged.Ex == pytest.approx(1.033, abs=0.005)
    assert proc.stderr.count("amfe: warning:") == 1


def test_the_issues_command_under_the_auto_solver(bed_file, converged, tmp_path):
    # auto factorises this bed: -ksp_atol has no effect, and the output says so
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", bed_file, "-o", str(out), "--quiet", "-ksp_atol", "1e3"])
    assert proc.returncode == 0, proc.stderr
    r = json.loads(out.read_text())
    assert r["solver"]["method"] == "cholesky"
    assert r["properties"]["Ex"] == pytest.approx(converged.Ex, rel=1e-12)
    assert r["warnings"] and "-ksp_atol" in r["warnings"][0] and "never used" in proc.stderr


def test_accept_unconverged_in_python(bed_file, converged):
    r = amfe.homogenize(bed_file, max_it=np.int64(1), accept_unconverged=True, solver="gamg")
    assert len(r.extra["warnings"]) == 6 and "DIVERGED_MAX_IT" in r.extra["warnings"][0]
    assert abs(r.Ex / converged.Ex - 1) > 1e-3
    with pytest.raises(AmfeError, match="accept_unconverged=True"):
        amfe.homogenize(bed_file, max_it=1, solver="gamg")


def test_converged_solve_meets_the_contract_without_warnings(converged):
    s = converged.solver
    assert converged.extra["warnings"] == []
    assert s["rtol"] == 1e-8 and s["residual_limit"] == pytest.approx(1e-7)
    assert max(s["residuals"]) <= s["residual_limit"]


@pytest.mark.parametrize("option", [["-ksp_rtol", "10"], ["-ksp_rtol", "0"], ["--rtol", "10"],
                                    ["-ksp_rtol", "abc"]])
def test_rtol_outside_0_1_is_refused_either_way(bed_file, option):
    proc = run_cli(["homogenize", bed_file, "--quiet", *option])
    assert proc.returncode == 2
    assert "must lie in (0, 1)" in one_error_line(proc.stderr)
    assert "frame:" not in proc.stderr   # refused before any work


def test_rtol_outside_0_1_is_refused_in_python(bed_file):
    for kw in ({"rtol": 10}, {"rtol": 0.0}, {"petsc_options": {"ksp_rtol": 2}}):
        with pytest.raises(AmfeError, match=r"must lie in \(0, 1\)"):
            amfe.homogenize(bed_file, **kw)


def test_solver_record_has_the_rtol_actually_used(bed_file, tmp_path):
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", bed_file, "-o", str(out), "--quiet", "-ksp_rtol", "1e-5",
                    "--solver", "gamg"])
    assert proc.returncode == 0, proc.stderr
    s = json.loads(out.read_text())["solver"]
    assert s["rtol"] == 1e-5 and s["residual_limit"] == pytest.approx(1e-4)
    assert "rtol 1e-05" in proc.stdout
    assert max(s["residuals"]) > 1e-8   # it did stop earlier than the default would


# ------------------------------------------------------ item 2: unused PETSc options


def test_mistyped_petsc_options_get_one_warning(bed_file, converged, tmp_path):
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", bed_file, "-o", str(out), "--quiet", "-ksp_rtoll", "1e-3",
                    "-foo_bar", "3", "-ksp_converged_reason", "-options_left", "0"])
    assert proc.returncode == 0, proc.stderr
    warned = [ln for ln in proc.stderr.splitlines() if "never used" in ln]
    assert len(warned) == 1
    assert "-ksp_rtoll" in warned[0] and "-foo_bar" in warned[0]
    assert "-ksp_converged_reason" not in warned[0] and "-options_left" not in warned[0]
    assert "Linear solve converged" in proc.stdout
    r = json.loads(out.read_text())
    assert r["warnings"] == [warned[0].removeprefix("amfe: warning: ")]
    assert r["properties"]["Ex"] == pytest.approx(converged.Ex, rel=1e-12)   # no effect


def test_options_for_a_solver_not_used_are_named(bed_file):
    r = amfe.homogenize(bed_file, petsc_options={"pc_hypre_type": "boomeramg"})
    assert any("-pc_hypre_type" in w for w in r.extra["warnings"])
    r = amfe.homogenize(bed_file, petsc_options={"pc_type": "jacobi"})
    assert not any("never used" in w for w in r.extra["warnings"])


# ----------------------------------------------------------------- item 3: materials


def bed_with_attrs(tmp_path, name, **attrs):
    bed = generate_bed(size=ISSUE_SIZE, seed=0)
    keep = {k: v for k, v in bed.attrs.items() if not k.startswith("material_")}
    path = tmp_path / name
    write_bed(path, Bed(bed.centers, bed.radii, keep))
    with h5py.File(path, "r+") as f:   # as another program would write them (a Bed checks its own)
        for key, value in attrs.items():
            if key in f.attrs:
                del f.attrs[key]
            f.attrs[key] = value
    return str(path)


def test_partial_material_is_an_error_naming_the_missing(tmp_path, capsys):
    path = bed_with_attrs(tmp_path, "partial.h5", material_E=70e9)
    assert main(["homogenize", path, "--quiet"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "material_nu, material_psi" in line and "incomplete" in line


def test_material_without_density_is_the_files(tmp_path, converged):
    path = bed_with_attrs(tmp_path, "alu.h5", material_E=70e9, material_nu=0.28,
                          material_psi=0.08)
    r = amfe.homogenize(path)
    # C is linear in E (the frame is solved in units of E): a third of steel's
    assert r.Ex == pytest.approx(converged.Ex * 70 / 210, rel=1e-12)
    assert r.extra["material"] == {"E": 70e9, "nu": 0.28, "psi": 0.08, "source": "bed file"}


def test_default_material_is_reported(tmp_path, converged):
    path = bed_with_attrs(tmp_path, "none.h5")
    r = amfe.homogenize(path)
    assert r.extra["material"]["source"] == "default (steel)"
    assert converged.extra["material"]["source"] == "bed file"
    assert r.Ex == converged.Ex


def test_command_line_material_overrides_the_file(bed_file, converged, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["homogenize", bed_file, "--quiet", "-o", str(out), "--E", "70e9"]) == 0
    printed = capsys.readouterr().out
    r = json.loads(out.read_text())
    assert r["material"]["source"] == "command line (E); bed file (nu, psi)"
    assert "E 70 GPa" in printed and "command line (E)" in printed
    assert r["properties"]["Ex"] == pytest.approx(converged.Ex / 3, rel=1e-12)
    # all three given: the file's partial material no longer matters
    partial = bed_with_attrs(tmp_path, "partial.h5", material_E=1e9)
    assert main(["homogenize", partial, "--quiet", "-o", str(out), "--E", "210e9", "--nu",
                 "0.28", "--psi", "0.08"]) == 0
    r = json.loads(out.read_text())
    assert r["material"]["source"] == "command line"
    assert r["properties"]["Ex"] == pytest.approx(converged.Ex, rel=1e-12)


def test_pack_material_options_are_recorded(tmp_path, capsys):
    path = tmp_path / "b.h5"
    assert main(["pack", "-o", str(path), "--size", "0.15", "0.15", "0.08", "--E", "70e9",
                 "--nu", "0.3"]) == 0
    assert "E 70 GPa, nu 0.3, psi 0.08 (command line (E, nu); default (steel) (psi))" \
        in capsys.readouterr().out
    attrs = read_bed(path).attrs
    assert (attrs["material_E"], attrs["material_nu"], attrs["material_psi"]) == (70e9, 0.3, 0.08)
    assert main(["pack", "-o", str(path), "--scale", "small", "--E", "1e9"]) == 2


@pytest.mark.parametrize("attrs, named", [
    ({"material_E": "abc", "material_nu": 0.28, "material_psi": 0.08}, "material_E"),
    ({"material_E": [1e9, 2e9], "material_nu": 0.28, "material_psi": 0.08}, "material_E"),
    ({"seed": "abc"}, "seed"),
    ({"size": [1e-3, 1e-3]}, "size"),
    ({"material_E": 70e9, "material_nu": 0.6, "material_psi": 0.08}, "nu=0.6"),
])
def test_attributes_of_the_wrong_type_are_one_clear_error(tmp_path, capsys, attrs, named):
    path = bed_with_attrs(tmp_path, "bad.h5", **attrs)
    assert main(["homogenize", path, "--quiet"]) == 2
    assert named in one_error_line(capsys.readouterr().err)


def test_resolve_material_unit():
    m, rec = resolve_material({"material_E": 1e9, "material_nu": 0.2, "material_psi": 0.1},
                              given={"psi": 0.05})
    assert (m.E, m.nu, m.psi) == (1e9, 0.2, 0.05)
    assert rec["source"] == "bed file (E, nu); command line (psi)"
    with pytest.raises(AmfeError, match="real number"):
        resolve_material({"material_E": True, "material_nu": 0.2, "material_psi": 0.1})


# -------------------------------------------------------------- item 5: complex arrays


@pytest.mark.parametrize("change, dtype", [
    (lambda c, r: (c + 1e-9j, r), "complex128"),
    (lambda c, r: (c, r.astype(complex)), "complex128"),
    (lambda c, r: (c > 0, r), "bool"),
    (lambda c, r: (c.astype(str), r), "<U"),
    (lambda c, r: (c.astype(object), r), "object"),
])
def test_non_real_arrays_are_refused(change, dtype):
    bed = generate_bed(size=ISSUE_SIZE, seed=0)
    with pytest.raises(AmfeError, match=f"must hold real numbers.*{dtype}"):
        amfe.homogenize(change(bed.centers, bed.radii))


def test_real_arrays_of_other_dtypes_give_the_same_answer(converged):
    bed = generate_bed(size=ISSUE_SIZE, seed=0)
    r = amfe.homogenize((bed.centers.tolist(), list(bed.radii)))
    # plain arrays carry no recorded size: V is the spheres' box, so compare Ex V
    assert r.Ex * r.volume == pytest.approx(converged.Ex * converged.volume, rel=1e-12)


# ------------------------------------------------------- items 6 and 7: outputs first


def test_output_over_the_input_is_refused(bed_file, capsys):
    before = open(bed_file, "rb").read()
    assert main(["homogenize", bed_file, "-o", bed_file]) == 2
    assert "would destroy the input" in one_error_line(capsys.readouterr().err)
    assert open(bed_file, "rb").read() == before


@pytest.mark.parametrize("bad", ["/proc/x.json", "DIR", "FILE/x.json", "--vtu FILE"])
def test_bad_output_paths_are_refused_before_any_work(bed_file, tmp_path, capsys, bad):
    (tmp_path / "file").write_text("x")
    bad = bad.replace("DIR", str(tmp_path)).replace("FILE", str(tmp_path / "file"))
    args = bad.split() if bad.startswith("--") else ["-o", bad]
    assert main(["homogenize", bed_file, *args]) == 2    # progress on: no "frame:" line
    err = capsys.readouterr().err
    assert "cannot write" in one_error_line(err) and "frame:" not in err


def test_full_disk_on_the_result_keeps_the_old_file(bed_file, tmp_path, capsys, monkeypatch):
    import errno
    out = tmp_path / "r.json"
    out.write_text("old\n")

    def no_space(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("amfe.io.atomic.os.fsync", no_space)
    assert main(["homogenize", bed_file, "--quiet", "-o", str(out)]) == 2
    assert "no space left" in one_error_line(capsys.readouterr().err).lower()
    assert out.read_text() == "old\n" and sorted(os.listdir(tmp_path)) == ["r.json"]


def test_pack_output_is_checked_before_generating(tmp_path, capsys):
    assert main(["pack", "-o", str(tmp_path), "--size", "100", "100", "100"]) == 2
    assert "is a directory" in one_error_line(capsys.readouterr().err, "pack")


# ------------------------------------------------------------ items 10 and 11: sizes, seeds


@pytest.mark.parametrize("size, limit", [(["100", "100", "100"], None), (["1e300", "1", "1"], None),
                                         (["10", "10", "3"], "8G")])
def test_absurd_pack_sizes_are_refused_with_an_estimate(tmp_path, capsys, size, limit):
    extra = ["--max-memory", limit] if limit else []
    rc = main(["pack", "-o", str(tmp_path / "b.h5"), "--size", *size, *extra])
    assert rc == 2
    line = one_error_line(capsys.readouterr().err, "pack")
    assert "needs about" in line and "GiB" in line and "--max-memory" in line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("seed", [str(2**64), "-1", str(10**30)])
def test_pack_seeds_outside_the_generator_range_are_refused(tmp_path, capsys, seed):
    assert main(["pack", "-o", str(tmp_path / "b.h5"), "--seed", seed]) == 2
    assert "[0, 2**64)" in one_error_line(capsys.readouterr().err, "pack")
    assert list(tmp_path.iterdir()) == []


def test_largest_seed_is_written_and_read_back(tmp_path, capsys):
    path = tmp_path / "b.h5"
    assert main(["pack", "-o", str(path), "--size", "0.15", "0.15", "0.08",
                 "--seed", str(2**64 - 1)]) == 0
    assert read_bed(path).attrs["seed"] == 2**64 - 1


def test_bed_file_declaring_2e9_particles_is_refused_before_reading(tmp_path, capsys):
    path = tmp_path / "huge.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("particles/centers", shape=(2_000_000_000, 3), dtype="f8",
                         chunks=(1024, 3))
        f.create_dataset("particles/radii", shape=(2_000_000_000,), dtype="f8", chunks=(1024,))
    assert os.path.getsize(path) < 10_000
    assert main(["homogenize", str(path), "--max-memory", "16G"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "2000000000 particles" in line and "needs about 119 GiB" in line


def test_max_memory_refuses_a_solve_before_any_work(bed_file, capsys):
    assert main(["homogenize", bed_file, "--max-memory", "1M"]) == 2
    err = capsys.readouterr().err
    line = one_error_line(err)
    assert f"{solve_bytes(168) / 2**30:.3g} GiB" in line and "frame:" not in err
    assert main(["homogenize", bed_file, "--max-memory", "lots"]) == 2


def test_parse_size():
    assert parse_size("8G") == 8 * 2**30 and parse_size("1.5GiB") == 1.5 * 2**30
    assert parse_size("500m") == 500 * 2**20 and parse_size("4096") == 4096
    for bad in ("", "-1G", "nanG", "8Q"):
        with pytest.raises(AmfeError):
            parse_size(bad)


MEASURE = """
import json, sys
import amfe
from amfe.model.frame import build_frame
from amfe.solvers.choice import solve_features


def peak():  # VmHWM: this process's peak resident set [kB] (ru_maxrss keeps the parent's)
    return int(next(ln for ln in open("/proc/self/status") if ln.startswith("VmHWM")).split()[1])


size, what = tuple(float(s) * 1e-3 for s in sys.argv[1:4]), sys.argv[4]
bed = amfe.generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), seed=1)   # imports done
if what != "generate":
    amfe.homogenize(bed, solver=what)
    bed = amfe.generate_bed(size=size, seed=2)
    features = solve_features(build_frame(bed.centers, bed.radii))
base = peak()
if what == "generate":
    bed, features = amfe.generate_bed(size=size, seed=2), {}
else:
    assert amfe.homogenize(bed, solver=what).solver["method"] == what
print(json.dumps({"used": (peak() - base) * 1024, **features}))
"""


@pytest.mark.parametrize("size, what", [((0.6, 0.6, 0.3), "generate"), ((0.4, 0.4, 0.2), "gamg"),
                                        ((0.4, 0.4, 0.2), "cholesky")])
def test_memory_estimates_bound_the_measured_peak(size, what):
    # peak resident memory of a fresh process (the constants of amfe.model.memory are these
    # measurements on more beds, rounded up)
    proc = subprocess.run([sys.executable, "-c", MEASURE, *map(str, size), what],
                          capture_output=True, text=True, env=MPI_ENV, cwd=ROOT, timeout=120)
    m = json.loads(proc.stdout)
    if what == "generate":
        est = generation_bytes(tuple(s * 1e-3 for s in size), 12.5e-6 / 1.095)
    elif what == "gamg":
        est = solve_bytes(m["n_particles"])
    else:
        est = direct_bytes(m["n_particles"], m["n_bonds"], m["fill_ratio"])
    assert m["used"] <= est <= 2 * m["used"]


def test_auto_does_not_factorise_beyond_the_memory_limit(bed_file, converged):
    est = direct_bytes(converged.n_particles, converged.n_bonds, 10.0)
    r = amfe.homogenize(bed_file, max_memory=est / 2)
    assert r.solver["method"] == "gamg" and "factorising 168 particles" in r.solver["reason"]
    with pytest.raises(AmfeError, match="factorising 168 particles"):
        amfe.homogenize(bed_file, max_memory=est / 2, solver="cholesky")


# ------------------------------------------------- items 12 and 13: coordinates, messages


@pytest.mark.parametrize("how, match", [("scale", "radii lie outside"),
                                        ("far", "mean radii from the origin")])
def test_extreme_coordinates_are_one_clear_error(tmp_path, capsys, how, match):
    bed = generate_bed(size=ISSUE_SIZE, seed=0)
    c, r = bed.centers.copy(), bed.radii.copy()
    if how == "scale":
        c, r = c * 1e-300, r * 1e-300
    else:
        c[0, 0] = 1e300
    with pytest.raises(AmfeError, match=match):
        amfe.homogenize((c, r))
    path = tmp_path / "x.h5"
    with h5py.File(path, "w") as f:
        f["particles/centers"], f["particles/radii"] = c, r
    assert main(["homogenize", str(path), "--quiet"]) == 2
    assert match in one_error_line(capsys.readouterr().err)


def test_tiny_a_star_cap_names_its_range_not_petsc(bed_file, capsys):
    assert main(["homogenize", bed_file, "--cap-a-star", "1e-300"]) == 2
    err = capsys.readouterr().err
    line = one_error_line(err)
    assert "a* cap must lie in [0.001," in line and "PETSc" not in line and "frame:" not in err


def test_straight_chain_spans_no_volume(tmp_path, capsys):
    n, d = 30, np.ones(3) / np.sqrt(3.0)
    path = tmp_path / "chain.h5"
    write_bed(path, Bed(np.arange(n)[:, None] * 1.8e-6 * d, np.full(n, 1e-6)))
    assert main(["homogenize", str(path), "--quiet"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "span no volume" in line and "ill-conditioned" not in line
