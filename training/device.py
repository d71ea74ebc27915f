"""Where networks train: ``--device auto|cpu|cuda``.

Training runs on the device chosen here; inference and the checkpoint stay on
the CPU (:func:`amfe.training.train.train_member` moves the trained network
back), so a checkpoint made on a GPU loads and predicts on a machine without
one. On a fresh machine pip installs torch's CUDA build, which uses a GPU
when torch sees one (README, set-up).
"""
import torch

from amfe.errors import AmfeError

DEVICES = ("auto", "cpu", "cuda")


def resolve_device(name="auto"):
    """The torch.device for ``name``: "auto" is CUDA when torch sees a GPU, else the CPU."""
    if name not in DEVICES:
        raise AmfeError(f"unknown device {name!r}; choose one of {', '.join(DEVICES)}")
    cuda = torch.cuda.is_available()
    if name == "cuda" and not cuda:
        raise AmfeError(f"--device cuda: torch {torch.__version__} sees no CUDA device (built "
                        f"with CUDA {torch.version.cuda or 'none'}); use --device cpu or auto")
    return torch.device("cuda" if name == "cuda" or (name == "auto" and cuda) else "cpu")


def device_of(net):
    """The device a network's parameters are on."""
    return next(net.parameters()).device
