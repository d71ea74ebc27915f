"""`amfe homogenize --bc all`: KUBC and SUBC (and periodic) side by side with their gap.

Also the note every homogenize output carries when a modulus exceeds the
particles' own E (docs/model.md, sections 5a and 9).
"""
import json
import os
import sys
import textwrap

import numpy as np

from amfe.vocab import CONSTANT_NAMES

GAP_MEANING = (
    "gap = (KUBC - SUBC) / KUBC. KUBC prescribes the boundary's displacements, SUBC its "
    "forces; their energies are ordered, e:C_subc:e <= e:C_kubc:e for every strain e, and so "
    "are the moduli E and G, but not the Poisson ratios, which may fall either side. A small "
    "gap means the bed is large enough for its boundary not to matter. With V the bed's own "
    "box the two need NOT bracket the periodic value: a finite bed lacks the bonds that "
    "cross the box's faces on the torus, which lowers both (on a cubic lattice n particles "
    "wide both sit 1/n below it); the periodic column, where shown, is the material's own "
    "stiffness (docs/model.md, section 9).")

ABOVE_E = ("note: {names} {verb} the particles' own E = {E:.4g} GPa. This is not a unit error: "
           "the paper's springs (eqs. 1-4) at large contact radii make small bonded beds stiffer "
           "than the solid (docs/model.md, sections 5a and 9, explain it with numbers).")
ABOVE_VOIGT = ("warning: {names} {verb} {bound:.4g} GPa, the solid fraction {phi:.4f} times the "
               "solid's E = {E:.4g} GPa: no porous solid of this material is that stiff (under "
               "KUBC and periodic conditions alike the affine strain bounds the energy, the "
               "Voigt bound), so the voxel solve did not reach the voxel model's answer; solve "
               "again with a tighter tolerance (--rtol)")


def above_e_note(properties, E, model=None):
    """The note for moduli above the particles' E [Pa], or None when none is.

    model: the result's "model" record (the voxel model's: its solid fraction phi);
    a voxel model's Young's moduli lie below phi E, so one above it is a warning, and
    the frame's note (the paper's springs) is never said of it.
    """
    if model and model.get("name") == "voxel":
        phi = float(model["solid_fraction"])
        names = [k for k in CONSTANT_NAMES
                 if k.startswith("E") and properties[k] > phi * E * (1 + 1e-9)]
        return ABOVE_VOIGT.format(names=", ".join(names), verb=_verb(names), bound=phi * E / 1e9,
                                  phi=phi, E=E / 1e9) if names else None
    names = [k for k in CONSTANT_NAMES if k.startswith("E") and properties[k] > E]
    return ABOVE_E.format(names=", ".join(names), verb=_verb(names),
                          E=E / 1e9) if names else None


def _verb(names):
    return "exceeds" if len(names) == 1 else "exceed"


def compare(results):
    """Gaps of {bc: Result} as plain data: per constant (K - S) / K, and the energy gap.

    energy_gap: min over the six unit and 200 random strains of
    (e C_kubc e - e C_subc e) / (e C_kubc e); negative means the ordering is
    violated (possible only where a hull vertex is not prescribed by KUBC).
    """
    from amfe.model.subc import energy_gap

    k, s = results["kubc"], results["subc"]
    return {"energy_gap": energy_gap(np.asarray(k.C), np.asarray(s.C)),
            "relative_gap": {n: (k.properties[n] - s.properties[n]) / k.properties[n]
                             for n in CONSTANT_NAMES}}


def table(results, gaps):
    """The side-by-side table, the energy gap and what the gap means, as text."""
    names = list(results)
    head = f"  {'':6s} {'':4s}" + "".join(f"{n:>11s}" for n in names) + f"{'gap K-S':>10s}"
    per = "periodic" in results
    if per:
        head += f"{'K/per-1':>10s}{'S/per-1':>10s}"
    lines = [head]
    for c in CONSTANT_NAMES:
        unit, scale = ("GPa", 1e-9) if not c.startswith("nu") else ("", 1.0)
        row = f"  {c:6s} {unit:4s}" + "".join(f"{results[n].properties[c] * scale:11.4g}"
                                              for n in names)
        row += f"{100 * gaps['relative_gap'][c]:9.2f}%"
        if per:
            p = results["periodic"].properties[c]
            row += "".join(f"{100 * (results[n].properties[c] / p - 1):9.2f}%"
                           for n in ("kubc", "subc"))
        lines.append(row)
    g = gaps["energy_gap"]
    lines.append(f"energy ordering: min over 206 strains of (eKe - eSe)/eKe = {g:.3g} "
                 + ("(holds)" if g >= -1e-9 else "(VIOLATED: a hull vertex is not prescribed "
                    "by KUBC, so its Bagi strain is not the applied one)"))
    lines.append(textwrap.fill(GAP_MEANING, 100))
    return "\n".join(lines)


def run_all(args, bed, comm, summary, **options):
    """Solve every condition the bed allows and print them side by side (rank 0).

    options: more keywords of :func:`amfe.api.homogenize` (material, accept_unconverged, ...).
    """
    from amfe.api import homogenize
    from amfe.io.atomic import write_json
    from amfe.io.paths import is_stdout
    from amfe.io.result_meta import HEADER_KEYS

    results = homogenize(bed, comm=comm, a_star_cap=args.cap_a_star, rtol=args.rtol,
                         vtu_dir=args.vtu, bc="all", diagnose=args.diagnose,
                         progress=not args.quiet, input_path=args.bed, **options)
    if comm.rank != 0:
        return 0
    gaps = compare(results)
    # `-o -` (or /dev/stdout): the JSON alone on stdout, the tables on stderr (it wrote a file "-")
    to_stdout = args.output is not None and is_stdout(args.output)
    out = sys.stderr if to_stdout else sys.stdout
    if args.output:
        head = {k: v for k, v in results["kubc"].to_dict().items()  # the bed's header;
                if k in HEADER_KEYS and k != "counts"}                # counts: per condition
        data = {**head, "bc": "all", **gaps,
                "conditions": {n: r.to_dict() for n, r in results.items()}}
        if to_stdout:
            print(json.dumps(data, indent=2), flush=True)
        else:
            write_json(args.output, data)
    for name, r in results.items():
        print(f"== {name}", file=out)
        print(summary(r.to_dict(), args.bed, vtu=args.vtu and os.path.join(args.vtu, name)),
              file=out)
    print("== bounds (docs/model.md, section 9)", file=out)
    print(table(results, gaps), file=out)
    note = above_e_note(results["kubc"].properties, results["kubc"].extra["material"]["E"])
    if note:
        print(textwrap.fill(note, 100), file=out)
    if args.output and not to_stdout:
        print(f"wrote {args.output}")
    return 0
