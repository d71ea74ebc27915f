"""The surrogate's data, training, calibration and evaluation."""
