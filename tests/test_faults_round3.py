"""Issue 45, round three of the faults: a Bed owns its arrays (item 4), stray pieces do not
define the box (item 6, the one box rule of amfe.model.carrying), VTU sets own their
directory (item 7) and corrupt HDF5 chunks give one line (item 9). docs/hard_cases.md."""
import os

import numpy as np
import pytest
from helpers import homogenize_arrays

from amfe.errors import AmfeError
from amfe.model.bed import Bed, generate_bed
from amfe.model.carrying import GivenBox, box_rule, component_labels, stray_pieces
from amfe.model.frame import build_frame


# --------------------------------------------------------------- item 4: a Bed's arrays
def test_bed_copies_and_locks_its_arrays():
    b = generate_bed(size=(110e-6, 110e-6, 100e-6), seed=1)
    x, r = np.array(b.centers), np.array(b.radii)
    bed = Bed(x, r)
    x[0, 0] = np.nan                      # written after the check: must not reach the bed
    r[1] = np.inf
    assert np.isfinite(bed.centers).all() and np.isfinite(bed.radii).all()
    assert bed.centers[0, 0] == b.centers[0, 0] and bed.radii[1] == b.radii[1]
    with pytest.raises(ValueError):
        bed.centers[0, 0] = np.nan
    with pytest.raises(ValueError):
        bed.radii[0] = -1.0
    assert build_frame(bed.centers, bed.radii).n_input == b.n


# --------------------------------------------------------------- item 6: strays and the box
def _issue_bed():
    """The issue's bed: a generated bed (100 particles, ~ the issue's 99) without its recorded
    size, plus a bonded tetrahedron of 4 strays one bed width away along x."""
    b = generate_bed(size=(110e-6, 110e-6, 100e-6), seed=1)
    x, r = b.centers, b.radii
    lo, hi = x.min(0), x.max(0)
    w = hi - lo
    R = r.mean()
    c = np.array([hi[0] + w[0], lo[1] + w[1] / 2, lo[2] + w[2] / 2])
    tet = np.array([[0, 0, 0], [1.8, 0, 0], [0.9, 1.56, 0], [0.9, 0.52, 1.47]]) * R
    return x, r, np.vstack([x, c + tet]), np.concatenate([r, np.full(4, R)])


def test_strays_one_bed_width_away_do_not_set_the_box():
    x, r, xs, rs = _issue_bed()
    fr = build_frame(xs, rs)
    assert fr.n_particles == x.shape[0] and fr.kept.max() < x.shape[0]   # strays removed
    assert fr.removed["particles"] == 4 and fr.box_source == "spheres' box"
    ref = build_frame(x, r)
    assert np.allclose(fr.size * fr.length_scale, ref.size * ref.length_scale, rtol=1e-12)
    alone = homogenize_arrays(x, r, solver="cholesky")
    both = homogenize_arrays(xs, rs, solver="cholesky")
    C0, C1 = np.array(alone["C"]), np.array(both["C"])
    assert np.abs(C1 - C0).max() <= 1e-10 * np.abs(C0).max()
    assert both["volume"] == pytest.approx(alone["volume"], rel=1e-12)
    assert any("4 particles" in w for w in both["warnings"])


def test_a_small_piece_inside_the_bed_is_no_stray_and_equal_blocks_are_none():
    x, r, xs, rs = _issue_bed()
    from amfe.model.bonds import find_pairs
    L = r.mean()
    labels = component_labels(xs.shape[0], *find_pairs(xs / L, rs / L))
    assert stray_pieces(xs / L, rs / L, labels).size == 1
    labels0 = component_labels(x.shape[0], *find_pairs(x / L, r / L))
    assert stray_pieces(x / L, r / L, labels0).size == 0
    # two equal blocks apart: neither is small, neither is a stray (both carry, as before)
    two = np.vstack([x, x + [3 * np.ptp(x[:, 0]), 0, 0]])
    labels2 = component_labels(two.shape[0], *find_pairs(two / L, np.tile(r, 2) / L))
    assert stray_pieces(two / L, np.tile(r, 2) / L, labels2).size == 0


def test_box_rule_sources_and_a_given_box():
    b = generate_bed(size=(110e-6, 110e-6, 100e-6), seed=1)
    x, r, size = b.centers, b.radii, b.attrs["size"]
    L, note, source = box_rule(x, r, size)
    assert source == "recorded size" and note is None and np.allclose(L, size)
    assert box_rule(x, r)[2] == "spheres' box"
    assert box_rule(x, r, [s / 2 for s in size])[2] == "spheres' box"
    given = np.array(size) * 1.1
    L, note, source = box_rule(x, r, size, given=given)
    assert source == "given box" and np.array_equal(L, given)
    with pytest.raises(AmfeError, match="given box .* does not hold the load-carrying centres"):
        box_rule(x, r, size, given=np.array(size) * 0.5)
    with pytest.raises(AmfeError, match="three positive lengths"):
        box_rule(x, r, given=[1e-4, -1, 1e-4])
    fr = build_frame(x, r, size=GivenBox(given))
    assert fr.box_source == "given box"
    assert fr.volume * fr.length_scale**3 == pytest.approx(np.prod(given), rel=1e-12)
    per = generate_bed(size=(110e-6, 110e-6, 100e-6), seed=1, periodic=True)
    assert build_frame(per.centers, per.radii, box=per.attrs["periodic"]).box_source \
        == "periodic box"


# --------------------------------------------------------------- item 9: damaged HDF5 chunks
def _compress(path, name, chunk_rows=4):
    import h5py
    with h5py.File(path, "a") as f:
        a = f[name][()]
        del f[name]
        f.create_dataset(name, data=a, chunks=(chunk_rows,) + a.shape[1:], compression="gzip",
                         shuffle=True)


def _corrupt_chunk(path, name, chunk=1):
    """Flip 16 bytes in the middle of compressed chunk ``chunk`` of /name: inflate() fails."""
    import h5py
    with h5py.File(path, "r") as f:
        info = f[name].id.get_chunk_info(chunk)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        b = fh.read(16)
        fh.seek(info.byte_offset + info.size // 2)
        fh.write(bytes(x ^ 0xFF for x in b))


def _damaged_dataset(tmp_path, name="images"):
    from cli_fixtures import tiny_dataset
    p = tmp_path / "tiny.h5"
    tiny_dataset(p)
    _compress(p, name)
    _corrupt_chunk(p, name)
    return p


ONE_LINE = "cannot read data set .*\\(a damaged or truncated file\\); restore it from a copy"


def test_a_damaged_chunk_of_a_data_set_is_one_line_for_check_and_train(tmp_path):
    from cli_fixtures import run_main
    p = _damaged_dataset(tmp_path)
    code, out, err = run_main(["dataset", "--check", p])
    assert code == 2 and "inflate() failed" in err and str(p) in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    code, _, err = run_main(["train", p, "-o", tmp_path / "m.pt", "--quiet", "--epochs", "1"])
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "damaged or truncated file" in err and str(p) in err
    assert not (tmp_path / "m.pt").exists()


def test_check_reads_every_chunk_even_of_a_dataset_it_does_not_load(tmp_path):
    """A damaged chunk in an extra dataset (a group load_dataset does not read) is found."""
    import h5py
    from cli_fixtures import run_main, tiny_dataset
    p = tmp_path / "tiny.h5"
    tiny_dataset(p)
    code, _, err = run_main(["dataset", "--check", p])
    assert code == 1 and "damaged" not in err   # a synthetic file: layout problems, no damage
    with h5py.File(p, "a") as f:
        f.create_dataset("extra/notes", data=np.arange(4000.0), chunks=(500,),
                         compression="gzip")
    _corrupt_chunk(p, "extra/notes")
    code, _, err = run_main(["dataset", "--check", p])
    assert code == 2 and "damaged or truncated file" in err


def test_training_reads_of_a_damaged_data_set_are_amfe_errors(tmp_path):
    from training.data import BedDataset, read_rows
    p = _damaged_dataset(tmp_path)
    with pytest.raises(AmfeError, match=ONE_LINE):
        read_rows(p)
    ds = BedDataset(p)               # status and labels are sound: opening works
    with pytest.raises(AmfeError, match=ONE_LINE):
        [ds[k] for k in range(len(ds))]


def test_a_damaged_label_shard_is_one_line(tmp_path):
    import h5py

    from amfe.dataset.labels import IDENTITY, TABLE_FORMAT, read_tables
    p = tmp_path / "shard.h5"
    with h5py.File(p, "w") as f:
        f.attrs.update({k: 1 for k in IDENTITY})
        f.attrs["format"] = TABLE_FORMAT
        f.create_dataset("index", data=np.arange(4000), chunks=(500,), compression="gzip")
    _corrupt_chunk(p, "index")
    with pytest.raises(AmfeError, match="cannot read label table .*shard.h5: .*inflate.*"
                       "damaged or truncated file\\); export it again"):
        read_tables([p])
    from cli_fixtures import run_main
    code, _, err = run_main(["dataset", "--from-labels", p, "-o", tmp_path / "d.h5"])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "export it again" in err, err


# --------------------------------------------------------------- item 7: a VTU set owns DIR
def _fields(k=1):
    from test_vtu import tiny_fields
    return tiny_fields(k=k)


def test_user_files_named_like_case_files_survive_a_new_set(tmp_path):
    from amfe.io.vtu import write_fields_vtu
    (tmp_path / "case_mine.vtu").write_text("the user's")
    (tmp_path / "case_mine.vtp").write_text("the user's")
    write_fields_vtu(tmp_path, _fields(2))
    write_fields_vtu(tmp_path, _fields(1))            # the earlier set's case_yy.vtu goes
    assert (tmp_path / "case_mine.vtu").read_text() == "the user's"
    assert (tmp_path / "case_mine.vtp").read_text() == "the user's"
    assert not (tmp_path / "case_yy.vtu").exists() and (tmp_path / "case_xx.vtu").exists()


def test_a_planted_link_is_replaced_not_written_through(tmp_path):
    from amfe.io.vtu import write_fields_vtu
    outside = tmp_path / "outside.txt"
    outside.write_text("precious")
    d = tmp_path / "set"
    d.mkdir()
    os.symlink(outside, d / "case_xx.vtu")
    os.symlink(outside, d / "cases.json")
    write_fields_vtu(d, _fields(1))
    assert outside.read_text() == "precious"
    assert not os.path.islink(d / "case_xx.vtu") and not os.path.islink(d / "cases.json")
    assert (d / "case_xx.vtu").read_bytes().startswith(b"<?xml")


def test_a_second_writer_of_one_directory_is_refused(tmp_path):
    from amfe.io.vtu import write_fields_vtu
    from amfe.io.vtuset import LOCK_NAME, SetLock
    write_fields_vtu(tmp_path, _fields(1))
    before = {p: (tmp_path / p).read_bytes() for p in os.listdir(tmp_path)}
    with SetLock(tmp_path), pytest.raises(      # another run holds DIR (a live pid)
            AmfeError, match="being written by another amfe run .*wait for it"):
        write_fields_vtu(tmp_path, _fields(2))
    assert {p: (tmp_path / p).read_bytes() for p in os.listdir(tmp_path)} == before
    assert not (tmp_path / LOCK_NAME).exists()        # released by its holder, not by us
    import subprocess
    import sys
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    from amfe.io.atomic import host_name
    (tmp_path / LOCK_NAME).write_text(f'{{"pid": {dead}, "host": "{host_name()}"}}\n')
    with pytest.raises(AmfeError, match="stale lock .*remove the lock and run again: rm "):
        write_fields_vtu(tmp_path, _fields(2))
    os.remove(tmp_path / LOCK_NAME)
    write_fields_vtu(tmp_path, _fields(2))            # free again: the lock is gone after
    assert not (tmp_path / LOCK_NAME).exists() and (tmp_path / "case_yy.vtu").exists()


def test_two_processes_into_one_directory_never_mix(tmp_path):
    """Two writers at once: one set completes, the other is refused; the cases.pvd left
    lists exactly the files of one set, each with that set's sidecar."""
    import subprocess
    import sys
    code = ("import sys; sys.path.insert(0, 'tests'); from test_vtu import tiny_fields; "
            "from amfe.io.vtu import write_fields_vtu; from amfe.errors import AmfeError\n"
            "k = int(sys.argv[2])\n"
            "try:\n    [write_fields_vtu(sys.argv[1], tiny_fields(k=k)) for _ in range(5)]\n"
            "except AmfeError as e:\n    print('refused', e)\n")
    procs = [subprocess.Popen([sys.executable, "-c", code, str(tmp_path), str(k)],
                              stdout=subprocess.PIPE, text=True) for k in (1, 2)]
    outs = [p.communicate(timeout=120)[0] for p in procs]
    from amfe.io.pvd import read_collection, read_sidecar
    files = [os.path.basename(f) for _, f in read_collection(tmp_path / "cases.pvd")]
    assert files in (["case_xx.vtu"], ["case_xx.vtu", "case_yy.vtu"])
    assert [c["file"] for c in read_sidecar(tmp_path)["cases"]] == files
    assert all(o == "" or o.startswith("refused the ParaView set in") for o in outs)


def test_bc_all_removes_an_older_set_of_amfes_only(tmp_path):
    from amfe.io.vtu import write_fields_vtu
    from amfe.io.vtuset import clear_stale_sets
    write_fields_vtu(tmp_path, _fields(2))                        # an older top-level set
    write_fields_vtu(tmp_path / "periodic", _fields(2))           # another bed's periodic/
    (tmp_path / "periodic" / "notes.txt").write_text("mine")
    (tmp_path / "mine.vtu").write_text("mine")
    for sub in ("kubc", "subc"):
        write_fields_vtu(tmp_path / sub, _fields(1))
    clear_stale_sets(tmp_path, ["kubc", "subc"])
    assert sorted(os.listdir(tmp_path)) == ["kubc", "mine.vtu", "periodic", "subc"]
    assert os.listdir(tmp_path / "periodic") == ["notes.txt"]
    assert sorted(os.listdir(tmp_path / "kubc")) == ["case_xx.vtu", "cases.json", "cases.pvd"]
    write_fields_vtu(tmp_path / "periodic", _fields(2))
    os.remove(tmp_path / "periodic" / "notes.txt")
    clear_stale_sets(tmp_path, ["kubc", "subc"])
    assert not (tmp_path / "periodic").exists()                   # emptied: gone


@pytest.fixture(scope="module")
def bed_file(tmp_path_factory):
    from amfe.io.bedfile import write_bed
    p = tmp_path_factory.mktemp("bed") / "bed.h5"
    write_bed(p, generate_bed(size=(110e-6, 110e-6, 100e-6), seed=1))
    return p


def test_bc_all_on_the_command_line_leaves_no_old_set_for_view(bed_file, tmp_path):
    from cli_fixtures import run_main

    from amfe.io.vtu import write_fields_vtu
    d = tmp_path / "v"
    write_fields_vtu(d, _fields(2))
    write_fields_vtu(d / "periodic", _fields(2))
    code, _, err = run_main(["homogenize", bed_file, "--bc", "all", "--vtu", d, "--quiet"])
    assert code == 0, err
    assert sorted(os.listdir(d)) == ["kubc", "subc"]


@pytest.mark.parametrize("inside", ["cases.json", "case_xx.vtu", "cases.pvd",
                                    "kubc/cases.json"])
def test_an_output_inside_the_set_is_refused(bed_file, tmp_path, inside):
    from cli_fixtures import run_main
    d = tmp_path / "v"
    (d / "kubc").mkdir(parents=True)
    bc = ["--bc", "all"] if "/" in inside else []
    code, _, err = run_main(["homogenize", bed_file, "--vtu", d, "-o", d / inside, *bc])
    assert code == 2 and "falls inside the ParaView set" in err, err
    assert len(err.strip().splitlines()) == 1
    assert os.listdir(d) == ["kubc"] and os.listdir(d / "kubc") == []     # nothing written
