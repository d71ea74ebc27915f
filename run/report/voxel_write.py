"""The report's model-level section from the stored model-error table (no solve).

section_voxel(root) returns markdown lines for docs/report.md from
root/docs/voxel_model_error.json (written by run/report/voxel_model_error.py; docs/model.md,
section 10), or [] when it is absent. The numbers are stored ones, with their date:
report.py does not rerun the voxel ladders (minutes to hours).
"""
import json
import os

KEYS = ["Ex", "Ey", "Ez", "E_mean", "G_yz"]


def section_voxel(root):
    path = os.path.join(root, "docs", "voxel_model_error.json")
    try:
        with open(path) as fh:
            beds = json.load(fh)["beds"]
    except (OSError, KeyError, ValueError):
        return []
    md = ["## 6. The model level: the paper's frame against the continuum", "",
          "Stored, not rerun by this page: docs/voxel_model_error.json (run/report/voxel_ladder.py, "
          "run/report/voxel_model_error.py; docs/model.md section 10). The continuum is the voxel "
          "finite-element model of the same spheres, extrapolated to H -> 0 with its error "
          "estimate; moduli in GPa; time and peak memory of the largest process on 2 ranks.", "",
          "| bed | model | " + " | ".join(KEYS) + " | s | GiB |",
          "|---|---|" + "---:|" * (len(KEYS) + 2)]
    for b in beds.values():
        c, f, r, fine = b["continuum"], b["frame"], b["ratio"], b["levels"][-1]
        md.append(f"| {b['label']} ({b['bc']}) | frame | "
                  + " | ".join(f"{f['properties'][k] / 1e9:.1f}" for k in KEYS)
                  + f" | {f['seconds']:.1f} | {f['peak_rss_bytes'] / 2**30:.2f} |")
        md.append(f"| | continuum (finest R/{fine['per_radius']:g}: s, GiB) | "
                  + " | ".join(f"{c[k]['value'] / 1e9:.1f} +- {c[k]['error'] / 1e9:.1f}"
                               for k in KEYS)
                  + f" | {fine['seconds']:.0f} | {fine['peak_rss_bytes'] / 2**30:.2f} |")
        md.append("| | frame / continuum | " + " | ".join(
            f"{r[k]['value']:.2f} +- {r[k]['error']:.2f}" for k in KEYS) + " | | |")
    return md + [""]
