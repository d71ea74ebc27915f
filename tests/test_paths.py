"""Output paths are checked before any work (amfe.io.paths)."""
import os

import pytest

from amfe.errors import AmfeError
from amfe.io.paths import check_output, check_output_dir


def test_good_output_passes_and_writes_nothing(tmp_path):
    out = tmp_path / "r.json"
    assert check_output(out) == str(out)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("make, match", [
    (lambda d: d, "is a directory"),
    (lambda d: d / "missing" / "r.json", "does not exist"),
    (lambda d: "/proc/x.json", "cannot write"),
])
def test_bad_outputs_are_refused(tmp_path, make, match):
    with pytest.raises(AmfeError, match=match):
        check_output(make(tmp_path))


def test_file_as_directory_is_refused(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(AmfeError, match="not a directory"):
        check_output(tmp_path / "file" / "x.json")


def test_output_equal_to_an_input_is_refused(tmp_path):
    bed = tmp_path / "bed.h5"
    bed.write_bytes(b"data")
    os.link(bed, tmp_path / "hard.h5")
    (tmp_path / "sym.h5").symlink_to(bed)
    for alias in (bed, tmp_path / "hard.h5", tmp_path / "sym.h5", tmp_path / "." / "bed.h5"):
        with pytest.raises(AmfeError, match="also an input"):
            check_output(alias, inputs=[bed])
    assert bed.read_bytes() == b"data"


def test_stdout_only_when_allowed(tmp_path):
    assert check_output("-", allow_stdout=True) == "-"
    os.chdir(tmp_path)
    assert check_output("-") == "-"   # a file named '-' in a writable directory


def test_output_dir(tmp_path):
    assert check_output_dir(tmp_path / "new" / "vtu") == str(tmp_path / "new" / "vtu")
    (tmp_path / "f").write_text("x")
    with pytest.raises(AmfeError, match="not a directory"):
        check_output_dir(tmp_path / "f")
    with pytest.raises(AmfeError, match="cannot write"):
        check_output_dir("/proc/vtu")
