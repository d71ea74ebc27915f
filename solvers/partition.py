"""Contiguous row blocks of particles per rank."""
import numpy as np


def row_ranges(n, size):
    """(size+1,) offsets splitting n particles into contiguous near-equal blocks."""
    counts = np.full(size, n // size, np.int64)
    counts[: n % size] += 1
    return np.concatenate([[0], np.cumsum(counts)])
