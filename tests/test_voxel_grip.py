"""KUBC's grip in the voxel model: the nodes inside the frame's boundary particles
(docs/model.md, section 10, "KUBC")."""
from dataclasses import replace

import numpy as np
from helpers import brute_grip
from test_voxel import solid_lattice

from amfe.model.bed import generate_bed
from amfe.model.hex8 import isotropic_D
from amfe.model.material import Material
from amfe.model.options import SolveOptions
from amfe.model.voxel import grip_nodes, load_carrying, voxel_solid, voxelize
from amfe.model.voxelmesh import build_mesh


def small_bed():
    """28 sintered particles, mean R 12.5 um, whose spheres reach none of the recorded box's
    upper faces (gaps of 0.57, 0.78 and 1.34 R): the case the face grip got wrong."""
    return generate_bed(size=(100e-6, 100e-6, 60e-6), seed=1)


def test_prescribed_nodes_are_those_inside_the_frames_boundary_particles():
    from amfe.model.frame import build_frame
    from amfe.model.kubc import boundary_particles
    bed = generate_bed(size=(100e-6, 100e-6, 80e-6), seed=1)   # 56 particles, 6 inside
    geo = voxel_solid(bed.centers, bed.radii, 5e-6, size=bed.attrs["size"])
    frame = build_frame(bed.centers, bed.radii, size=bed.attrs["size"])
    ids = np.sort(frame.kept[boundary_particles(frame.centers, frame.radii)])
    assert np.array_equal(np.sort(geo.grip_particles), ids) and 0 < ids.size < len(bed.radii)
    mesh = build_mesh(geo.solid)
    got = mesh.boundary_nodes(geo.grip)
    want = brute_grip(mesh, geo, bed.centers[ids], bed.radii[ids])
    assert np.array_equal(got, want)
    on_faces = brute_grip(mesh, geo)
    assert np.setdiff1d(got, on_faces).size > 0.5 * got.size    # mostly inside the box
    assert np.setdiff1d(on_faces, got).size > 0                 # face nodes no sphere grips


def test_grip_nodes_include_the_sphere_surface_and_nothing_beyond():
    from amfe.model.voxel import Grid
    grid = Grid(lo=np.zeros(3), n=np.array([4, 4, 4]), h=np.ones(3))
    mask = grip_nodes(np.array([[2.0, 2.0, 2.0]]), np.array([1.0]), grid)
    assert mask.shape == (5, 5, 5) and mask.sum() == 7          # the centre and its 6 neighbours
    assert mask[2, 2, 3] and not mask[2, 3, 3]


def test_a_piece_without_three_gripped_vertices_in_a_voxel_is_removed():
    solid = np.zeros((3, 3, 6), bool)
    solid[:, :, :2] = solid[:, :, 4:] = True                  # two blocks, x 0-2 and 4-6
    grip = np.zeros((4, 4, 7), bool)
    grip[0, 0, 0] = grip[0, 1, 0] = grip[1, 0, 0] = True      # 3 vertices of a corner voxel
    grip[0, 0, 6] = grip[0, 1, 6] = True                      # only 2 on the other block
    kept, pieces, voxels = load_carrying(solid, grip=grip)
    assert (pieces, voxels) == (1, 18) and kept[:, :, :2].all() and not kept[:, :, 4:].any()


def test_fully_solid_box_gripped_by_its_boundary_particles_gives_the_particles_C():
    """The 26 outer spheres of a 3^3 lattice cover the box's faces and more: the affine
    field is still the solution, and the reactions at the interior gripped nodes vanish."""
    from amfe.solvers.voxel import homogenize_voxel
    m = Material(E=200e9, nu=0.3)
    res = homogenize_voxel(solid_lattice(), SolveOptions(rtol=1e-12, material=m),
                           voxel_size=0.5e-5, initial="zero")
    grip = res.extra["model"]["grip"]
    assert grip["particles"] == 26 and 98 < grip["nodes"] < 125   # 98 face nodes of 125
    assert np.abs(np.array(res.C) - isotropic_D(m.E, m.nu)).max() <= 1e-10 * m.E


def Ez(geo):
    from amfe.model.averages import compliance_and_constants
    from amfe.solvers.petsc import init_petsc
    from amfe.solvers.voxel import voxel_stiffness
    C = voxel_stiffness(geo, SolveOptions(rtol=1e-8, material=Material()),
                        init_petsc().COMM_SELF)[0]
    return compliance_and_constants(C)[1]["Ez"]


def test_kubc_Ez_converges_in_H_where_the_box_faces_did_not():
    """docs/model.md, section 10: R/3 -> R/4 on the small bed moves Ez by 4.7 % with the
    particle grip, by -16 % with the old face grip (whose top face no sphere reaches)."""
    bed = small_bed()
    grip, face = [], []
    for h in (bed.radii.mean() / 3, bed.radii.mean() / 4):
        geo = voxel_solid(bed.centers, bed.radii, h, size=bed.attrs["size"])
        kept = load_carrying(voxelize(bed.centers[geo.kept], bed.radii[geo.kept], geo.grid))[0]
        grip.append(Ez(geo))
        face.append(Ez(replace(geo, solid=kept, grip=None, grip_particles=None)))
    change = [abs(v[1] / v[0] - 1) for v in (grip, face)]
    assert change[0] < 0.07 and change[0] < 0.5 * change[1]
    assert 5 * face[1] < grip[1] < 0.5 * 210e9                  # the face grip: nearly free
