"""Example 1: one powder bed, from generation to elastic constants and a ParaView file.

Run it as ``python examples/01_bed_to_constants.py [OUTDIR]``; add ``--tiny`` for a
bed of a few dozen particles (what the test suite runs).
"""
import sys
from pathlib import Path

import amfe

args = [a for a in sys.argv[1:] if a != "--tiny"]
out = Path(args[0] if args else "results/example1")
tiny = "--tiny" in sys.argv

# %% 1. Generate a bed: HCP layers of enlarged, jittered spheres (metres), as in
# docs/model.md, section 2. The same seed gives the same bed on any machine.
size = (0.1e-3, 0.1e-3, 0.06e-3) if tiny else (0.25e-3, 0.25e-3, 0.1e-3)
bed = amfe.generate_bed(size=size, seed=0)
print(f"1. generated {bed.n} particles in a {size[0] * 1e3:g} x {size[1] * 1e3:g} x "
      f"{size[2] * 1e3:g} mm box")

# %% 2. Save it in amfe's bed format (HDF5: /particles/centers, /particles/radii)
# and read it back: any tool that writes those two datasets can hand beds in.
out.mkdir(parents=True, exist_ok=True)
amfe.write_bed(out / "bed.h5", bed)
bed = amfe.read_bed(out / "bed.h5")
print(f"2. wrote and read {out / 'bed.h5'}")

# %% 3. Homogenize: six unit macro-strains on the boundary (KUBC), one PETSc
# operator, CG + GAMG; Bagi averages give C and S. fields=True keeps the
# displacements, rotations and bond forces of each load case.
result = amfe.homogenize(bed, rtol=1e-10, fields=True)
print("3.", result)

# %% 4. The constants are plain attributes (SI units); C and S are numpy arrays.
print(f"4. Ex = {result.Ex / 1e9:.1f} GPa, nu_xy = {result.nu_xy:.3f}, "
      f"C11 = {result.C[0, 0] / 1e9:.1f} GPa")

# %% 5. Fields: per case (xx, yy, zz, yz, xz, xy) and per unit strain.
f = result.fields
print(f"5. largest |u| in case xx: {abs(f.displacement[0]).max():.3g} m per unit strain; "
      f"largest axial bond force: {abs(f.axial_force[0]).max():.3g} N")

# %% 6. Write the JSON result and the ParaView files (open cases.pvd in ParaView).
result.to_json(out / "result.json")
paths = result.write_vtu(out / "vtu")
print(f"6. wrote {out / 'result.json'} and {paths[-1]}")
