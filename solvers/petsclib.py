"""PETSc, initialised: every module of solvers/ imports it from here, at module level.

PETSc reads the command line's options (-ksp_monitor, -log_view, -help) once,
when it is initialised. :func:`amfe.solvers.petsc.init_petsc` is the one place
that initialises it (``petsc4py.init(argv)``, as dolfinx and firedrake do): the
command line calls it with its PETSc options first (:func:`amfe.cli.main`),
before anything imports this module, so that a plain ``from petsc4py import
PETSc`` never initialises it without them. Imported first by a Python program,
this module initialises PETSc with no options (``amfe.homogenize``'s
``petsc_options`` then go into the options database per solve).

``import amfe`` stays lazy: only the face's functions import the solver layer.
"""
from amfe.solvers.petsc import init_petsc

PETSc = init_petsc()
