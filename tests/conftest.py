"""Test-session set-up that must run before numpy, scipy or PETSc load OpenBLAS."""
import os

# As amfe's command line does (amfe/cli/__init__.py): one BLAS thread, so that the
# in-process runs and the subprocesses of a test sum in the same order (a Cholesky
# label then agrees to the last bit).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import pytest  # noqa: E402  (after the thread settings above)

#: The small bed several fault tests share: 0.1 x 0.1 x 0.06 mm, seed 1 (28 particles).
SMALL_BED_SIZE = (0.1e-3, 0.1e-3, 0.06e-3)


@pytest.fixture(scope="module")
def bed():
    """The shared small bed (a test file may define its own ``bed``, which wins)."""
    from amfe.model.bed import generate_bed
    return generate_bed(size=SMALL_BED_SIZE, seed=1)


@pytest.fixture(scope="module")
def bed_path(bed, tmp_path_factory):
    """That bed written to a file: its path (str)."""
    from amfe.io.bedfile import write_bed
    path = tmp_path_factory.mktemp("bed") / "bed.h5"
    write_bed(path, bed)
    return str(path)
