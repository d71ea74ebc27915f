"""Section 4 of the report: the surrogate's networks against the solver at loose tolerances,
on held-out beds (split from run/report/measure.py)."""
import os
import time

import numpy as np

from run.report.measure import LABELS, _solve



def find_models(models_dir):
    """{name: (checkpoint dict, description)} of the networks found in ``models_dir``.

    NAME.pt for lenet5, alexnet, vgg, ensemble and bonds (run/train/train_surrogate.py's
    names; bonds is round 1's shipped one, which also reads the bond image);
    "Custom Net" is member 0 of the ensemble; "shipped" is the model amfe
    predict uses by default (amfe/models/multiscale_small.pt, docs/model_card.md).
    """
    from amfe.training.checkpoint import load_checkpoint
    found = {}
    names = {"lenet5": "LeNet-5", "alexnet": "AlexNet", "vgg": "VGG", "ensemble": "Custom Net x5",
             "bonds": "Custom Net x5 + bond image (round 1)"}
    for n, desc in names.items():
        p = os.path.join(models_dir or "", f"{n}.pt")
        if models_dir and os.path.exists(p):
            found[n] = (load_checkpoint(p), desc)
    from amfe.training.predict import default_model_path
    shipped = default_model_path()
    if shipped.is_file():
        ck = load_checkpoint(shipped)
        found["shipped"] = (ck, f"{ck['arch']} x{len(ck['members'])} + "
                                f"{' + '.join(ck['inputs'])} images (shipped)")
    if "ensemble" in found:
        ck = found["ensemble"][0]
        k0 = dict(ck, members=[ck["members"][0]], member_seeds=[ck["member_seeds"][0]],
                  history=[ck["history"][0]], spread=None,
                  training=dict(ck["training"], members=1, seconds=ck["history"][0]["seconds"]))
        found = {"custom": (k0, "Custom Net"), **found}
    return found


def surrogate_vs_solver(test_path, models_dir, n_solver_beds, rtols, log=print):
    """Section 4 on the held-out beds of ``test_path``: networks and the solver at loose rtol.

    Networks: mean relative error over the six labels and all held-out beds,
    ms per bed batched (one torch thread, and two), and the pixelation of a bed
    measured on ``n_solver_beds`` beds (and its bond image, for the networks
    that read it). Solver: the first ``n_solver_beds``
    beds regenerated from their seeds (amfe.model.scales.bed_for) and solved at each
    rtol, error against the data set's labels (rtol 1e-8), wall time per bed
    on one core including bonds and assembly.
    """
    import h5py
    import torch
    from petsc4py import PETSc

    from amfe.dataset.bondimage import bond_image
    from amfe.dataset.images import pixelate
    from amfe.model.scales import bed_for, get_scale
    from amfe.training.data import read_rows
    from amfe.training.metrics import property_metrics
    from amfe.training.predict import Surrogate
    from run.bench.surrogate import bench_batched

    torch.set_num_threads(1)
    with h5py.File(test_path, "r") as f:
        ok = np.flatnonzero(f["status"][:] == 0)
        labels = f["labels"][:][ok]
        seeds = f["seed"][:][ok]
        scale = f.attrs["scale"]
    scale = get_scale(scale.decode() if isinstance(scale, bytes) else str(scale))
    out = {"n_test": int(len(ok)), "networks": {}, "solver": []}
    for name, (ck, desc) in find_models(models_dir).items():
        sur = Surrogate(ck, name, backend="torch")   # timed on torch threads below
        images, _ = read_rows(test_path, ok, sur.inputs)
        pred = sur.predict(images)["mean"]
        m = property_metrics(pred, labels)
        ms, ms2 = bench_batched(sur, images, threads=(1, 2), batches=(None,),
                                repeats=3).values()   # one torch thread, then both cores
        out["networks"][name] = {
            "description": desc, "ms_per_bed": float(ms), "ms_per_bed_2threads": float(ms2),
            "mre": {k: float(m[k]["mre"]) for k in LABELS},
            "r2": {k: float(m[k]["r2"]) for k in LABELS},
            "mean_error": float(np.mean([m[k]["mre"] for k in LABELS])),
            "train_seconds": float(ck["training"]["seconds"]), "params": int(ck["n_parameters"]),
            "members": len(ck["members"]), "inputs": list(sur.inputs),
            "fine_tuned": bool(ck.get("init"))}
        log(f"  {desc:<26} {ms:7.3f} ms/bed  mean rel err "
            f"{100 * out['networks'][name]['mean_error']:.2f} %")
    pix, bonds, by_rtol = [], [], {rt: [] for rt in rtols}
    for k in range(min(n_solver_beds, len(ok))):
        bed = bed_for(scale, int(seeds[k]))
        t0 = time.perf_counter()
        pixelate(bed, scale.cell, scale.layer_thickness, box=[np.zeros(3), np.array(scale.size)],
                 spacing=scale.image_spacing)
        pix.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        bond_image(bed, scale.cell, scale.layer_thickness, box=[np.zeros(3), np.array(scale.size)])
        bonds.append(time.perf_counter() - t0)
        for rt in rtols:
            r = _solve(bed, PETSc.COMM_SELF, rtol=rt)
            err = [abs(r["properties"][n] / labels[k][j] - 1) for j, n in enumerate(LABELS)]
            by_rtol[rt].append((r["wall"], float(np.mean(err)), float(np.max(err))))
    out["pixelate_seconds"] = float(np.mean(pix)) if pix else float("nan")
    out["bond_image_seconds"] = float(np.mean(bonds)) if bonds else float("nan")
    for r in out["networks"].values():   # the images a network needs, per bed
        r["image_seconds"] = out["pixelate_seconds"] + (
            out["bond_image_seconds"] if "bonds" in r["inputs"] else 0.0)
    for rt in rtols:
        a = np.array(by_rtol[rt]).reshape(-1, 3)
        out["solver"].append({"rtol": rt, "beds": len(a), "seconds": float(a[:, 0].mean()),
                              "mean_error": float(a[:, 1].mean()),
                              "max_error": float(a[:, 2].max())})
        log(f"  solver CG + GAMG rtol {rt:.0e}: {a[:, 0].mean():.3f} s/bed, mean rel err "
            f"{100 * a[:, 1].mean():.2e} % ({len(a)} beds)")
    return out
