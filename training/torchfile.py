"""Read a plain ``torch.save`` file into numpy arrays, without importing torch.

Inference of the shipped models needs their weights, not torch: torch's
import alone takes 2.5-4 s on this project's machines, more than a whole
surrogate sweep of 36 beds should (docs/benchmarks.md, "Parameter sweeps").
This reader understands the zip archive ``torch.save`` writes (``*/data.pkl``
and one raw little-endian buffer a storage, ``*/data/<key>``) and, like
``torch.load(weights_only=True)``, unpickles only plain data: builtin values,
``collections.OrderedDict`` and tensors (``torch._utils._rebuild_tensor_v2``
over a typed storage). Any other global is refused with
:class:`pickle.UnpicklingError`, never imported or called.

Tensors come back as :class:`TensorArray`, a numpy array that remembers it
was a tensor, so :func:`amfe.training.checkpoint.save_checkpoint` writes it
back as one.
"""
import io
import pickle
import zipfile
from collections import OrderedDict

import numpy as np

#: torch's typed storages and the numpy dtype of their bytes (bfloat16 has none: refused).
STORAGE_DTYPES = {"FloatStorage": "<f4", "DoubleStorage": "<f8", "HalfStorage": "<f2",
                  "LongStorage": "<i8", "IntStorage": "<i4", "ShortStorage": "<i2",
                  "CharStorage": "i1", "ByteStorage": "u1", "BoolStorage": "?"}


class TensorArray(np.ndarray):
    """A numpy array read from a torch tensor (written back as a tensor by save_checkpoint)."""


class _Storage:
    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)


def _rebuild_tensor(storage, offset, size, stride, *_):
    """torch._utils._rebuild_tensor_v2's result as a TensorArray (a copy, C-contiguous)."""
    data, size, stride = storage, tuple(int(s) for s in size), tuple(int(s) for s in stride)
    offset = int(offset)
    if any(s < 0 for s in size + stride) or offset < 0:
        raise pickle.UnpicklingError("a tensor with a negative size, stride or offset")
    last = offset + sum((n - 1) * s for n, s in zip(size, stride)) if all(size) else offset - 1
    if last >= data.size:
        raise pickle.UnpicklingError(f"a tensor reaches element {last} of a storage of "
                                     f"{data.size}")
    view = np.lib.stride_tricks.as_strided(data[offset:] if data.size else data, shape=size,
                                           strides=tuple(s * data.itemsize for s in stride))
    return np.array(view).view(TensorArray)


class _Unpickler(pickle.Unpickler):
    """Plain data and tensors only (see the module docstring)."""

    def __init__(self, fh, read_storage):
        super().__init__(fh)
        self._read_storage = read_storage
        self._storages = {}

    def find_class(self, module, name):
        if (module, name) == ("collections", "OrderedDict"):
            return OrderedDict
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if module == "torch" and name in STORAGE_DTYPES:
            return _Storage(STORAGE_DTYPES[name])
        raise pickle.UnpicklingError(f"Unsupported global: GLOBAL {module}.{name} is not plain "
                                     "data")

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"
                and isinstance(pid[1], _Storage)):
            raise pickle.UnpicklingError(f"unsupported persistent id {pid!r:.60}")
        _, kind, key, _, numel = pid
        if key not in self._storages:
            self._storages[key] = self._read_storage(str(key), kind.dtype, int(numel))
        return self._storages[key]


def read_torch_file(path):
    """The object ``torch.save`` wrote to ``path`` (a zip archive), tensors as TensorArray.

    pickle.UnpicklingError for anything but plain data and tensors; zipfile.BadZipFile,
    KeyError or ValueError for a damaged archive.
    """
    with zipfile.ZipFile(path) as z:
        names = z.namelist()
        pkl = [n for n in names if n.endswith("/data.pkl") or n == "data.pkl"]
        if len(pkl) != 1:
            raise ValueError("no data.pkl in the archive")
        prefix = pkl[0][:-len("data.pkl")]
        order = z.read(prefix + "byteorder").decode().strip() if prefix + "byteorder" in names \
            else "little"
        if order != "little":
            raise ValueError(f"a {order}-endian checkpoint")

        def read_storage(key, dtype, numel):
            raw = z.read(f"{prefix}data/{key}")
            if len(raw) < numel * dtype.itemsize:
                raise ValueError(f"storage {key} holds {len(raw)} bytes, not "
                                 f"{numel * dtype.itemsize}")
            return np.frombuffer(raw, dtype, count=numel)

        return _Unpickler(io.BytesIO(z.read(pkl[0])), read_storage).load()


def _no_storage(*_):
    raise pickle.UnpicklingError("a legacy (not zip) torch file with tensors: re-save it with "
                                 "torch 1.6 or later")


def read_pickle(path):
    """A bare pickle file read with the same restrictions (a legacy or hand-made file)."""
    with open(path, "rb") as fh:
        return _Unpickler(fh, _no_storage).load()
