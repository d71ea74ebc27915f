"""Example 2: the CNN surrogate on a data-set bed, beside the solver.

Run it as ``python examples/02_surrogate.py``. The shipped model was trained
on `small` beds (0.6 x 0.6 x 0.3 mm); a data-set record's bed is regenerated
from its seed exactly as `amfe pack --scale small --seed SEED` does.
"""
import time

import numpy as np

import amfe
from amfe.model.scales import bed_for
from amfe.vocab import LABEL_NAMES

# %% 1. Regenerate record 0 of the held-out set of docs/surrogate.md from its seed.
bed = bed_for("small", 2834126987)
print(f"1. a `small` bed of {bed.n} particles")

# %% 2. Load the shipped surrogate (an ensemble; loaded weights-only) and predict.
surrogate = amfe.Surrogate.load()
t0 = time.perf_counter()
prediction = surrogate.predict(bed)
print(f"2. predicted in {1e3 * (time.perf_counter() - t0):.0f} ms "
      f"(imaging included), flagged: {bool(prediction['flagged'][0])}")

# %% 3. The solver's answer for the same bed, and the relative errors.
result = amfe.homogenize(bed)
solved = np.array([result.properties[k] for k in LABEL_NAMES])
predicted = prediction["mean"][0]
for name, p, s in zip(LABEL_NAMES, predicted, solved):
    scale = 1e9 if name.startswith("E") else 1.0
    print(f"3. {name:6s} surrogate {p / scale:9.4g}  solver {s / scale:9.4g}  "
          f"error {100 * (p - s) / s:+6.2f} %")
