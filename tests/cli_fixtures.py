"""Shared pieces of the command-line fault and fuzz tests: a tiny model, beds, and the checks
that a run ended as amfe promises (exit 0 with a finite result, or exit 2 with one line)."""
import contextlib
import hashlib
import io
import os

import torch
from test_training import TINY_ATTRS, _tiny_bed, write_synthetic

from amfe.cli import main


def tiny_dataset(path, n=40, failed=(3, 7)):
    """A synthetic data set of n 1 x 5 x 5 images (amfe's tiny scale)."""
    return write_synthetic(path, n=n, shape=(1, 5, 5), attrs=TINY_ATTRS, failed=failed)


def tiny_model(directory):
    """(model path, bed path): a 2-member Custom Net trained 1 epoch on a tiny data set, and a
    tiny generated bed it predicts."""
    from amfe.training.checkpoint import save_checkpoint
    from amfe.training.train import TrainConfig, train_model

    data = tiny_dataset(os.path.join(directory, "tiny.h5"))
    cfg = TrainConfig(epochs=1, batch_size=8, members=2, seed=1)
    ckpt = train_model(data, cfg, progress=False, log=lambda line: None)
    model = save_checkpoint(os.path.join(directory, "tiny.pt"), ckpt)
    bed = _tiny_bed(os.path.join(directory, "bed.h5"))
    return model, bed


def mutated_checkpoint(src, dst, change):
    """Copy the checkpoint ``src`` to ``dst`` after ``change(ckpt_dict)`` (in place)."""
    ckpt = torch.load(src, weights_only=True)
    change(ckpt)
    torch.save(ckpt, dst)
    return dst


def sha256(path):
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def run_main(argv):
    """amfe.cli.main(argv) in this process: (exit code, stdout, stderr).

    Any exception other than argparse's SystemExit propagates: the test fails
    with the traceback a user would have seen.
    """
    out, err = io.StringIO(), io.StringIO()
    threads = torch.get_num_threads()   # --threads must not slow the rest of the session
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:
            code = exc.code
        finally:
            torch.set_num_threads(threads)
    return code, out.getvalue(), err.getvalue()


def assert_one_error(code, err, command):
    """Exit 2, no traceback, and one error line (after the subcommand's usage for a bad option)."""
    assert code == 2, err
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert lines and lines[-1].startswith(f"amfe {command}: error: "), err
    assert sum("error:" in line for line in lines) == 1, err
    if len(lines) > 1:   # argparse: usage lines of this subcommand, then the one line
        assert lines[0].startswith(f"usage: amfe {command} "), err
        assert all(line.startswith(" ") for line in lines[1:-1]), err
    return lines[-1]
