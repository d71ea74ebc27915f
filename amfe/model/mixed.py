"""Mixed boundary conditions: the paper's six experiments (figure 2), each its own operator.

Uniaxial case i (xx, yy, zz): the particles at the two faces normal to axis i
(centre within one maximum radius of the face) get u_i = eps (x_i - x_c,i)
(frictionless grips: their other translations and all rotations are free);
every other face is traction-free. The constraints leave two translations and
the rotation about axis i free; they are handed to CG as the operator's null
space (the right-hand sides are consistent since K annihilates rigid motions).

Shear case ij (yz, xz, xy; engineering gamma): the particles at the two faces
normal to axis j get the full translation u = gamma (x_j - x_c,j) e_i (clamped
grips, as in a lap-shear test: with u_i alone prescribed the block would just
rotate, so a free face pair cannot carry shear); the other faces are
traction-free.

Strains are measured (Bagi, hull of the centres), not applied; C = Sig Eps^-1.
"""
import numpy as np

from amfe.model.averages import box_center
from amfe.model.loadcase import Group, rigid_body_modes

# (case name, loaded axis i, face-normal axis j): u_i = strain * (x_j - x_c,j)
CASES = (("xx", 0, 0), ("yy", 1, 1), ("zz", 2, 2), ("yz", 1, 2), ("xz", 0, 2), ("xy", 0, 1))


def face_particles(x, radii, axis):
    """(n,) bool: centres within one maximum radius of either face normal to ``axis``."""
    reach = radii.max()
    c = x[:, axis]
    return (c <= c.min() + reach) | (c >= c.max() - reach)


def mixed_groups(frame):
    """Six :class:`~amfe.solvers.loadcases.Group` s of one case each."""
    x = frame.centers
    xc = box_center(x)
    n = len(x)
    modes = rigid_body_modes(x, xc).reshape(6, n, 6)
    groups = []
    for name, i, j in CASES:
        held = face_particles(x, frame.radii, j)
        fixed = np.zeros((n, 6), bool)
        values = np.zeros((n, 6))
        values[:, i] = x[:, j] - xc[j]
        if i == j:
            fixed[held, i] = True
            others = [a for a in range(3) if a != i]
            null = np.stack([modes[others[0]], modes[others[1]], modes[3 + i]])
        else:
            fixed[held, :3] = True
            null = None
        groups.append(Group(fixed=fixed, values=[values], names=[name], null_modes=null))
    return groups
