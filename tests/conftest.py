"""Test-session set-up that must run before numpy, scipy or PETSc load OpenBLAS."""
import os

# As amfe's command line does (amfe/cli/__init__.py): one BLAS thread, so that the
# in-process runs and the subprocesses of a test sum in the same order (a Cholesky
# label then agrees to the last bit).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
